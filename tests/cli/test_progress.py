"""Progress in a log: complete lines at a fixed interval of the injected clock, and a last one."""

from evp.cli.progress import LogProgress, progress_of


def test_log_progress_prints_a_line_every_interval_and_at_the_end():
    now = [100.0]
    lines: list[str] = []
    progress = LogProgress("sample", 100, "frames", lines.append, lambda: now[0], interval_s=10.0)
    for _ in range(40):  # 40 frames, 0.5 s each: a line at 10 s and 20 s
        now[0] += 0.5
        progress.advance(1)
    progress.finish()
    assert lines == [
        "sample: 20/100 frames (20 %), 10 s, about 40 s left",
        "sample: 40/100 frames (40 %), 20 s, about 30 s left",
        "sample: 40 frames in 20 s",
    ]


def test_progress_off_a_terminal_writes_lines_to_stderr(capsys):
    with progress_of("sim", None, "frames", terminal=False) as progress:
        progress.total = 3
        progress.advance(3)
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.startswith("sim: 3 frames in ")
