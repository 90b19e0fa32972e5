"""``evp vocabulary``: bag-of-words vocabularies for place recognition, built and shown."""

from __future__ import annotations

from pathlib import Path

import typer

from evp.io.output_paths import writable_file

app = typer.Typer(help="Bag-of-words vocabularies for place recognition: build one, show one.", no_args_is_help=True)


@app.command("build")
def vocabulary_build(
    sources: list[Path] = typer.Argument(
        None, metavar="[DATASET]...", help="Recordings to train on (any format evp info reads); none: EVP's rendered training scenes."
    ),
    out: Path = typer.Option(..., "--out", help="Vocabulary file to write (.npz); use it with slam.vocabulary in a settings file."),
    every: int = typer.Option(5, "--every", min=1, help="With DATASETs: every this many frames."),
    frames_per_scene: int = typer.Option(40, "--frames-per-scene", min=1, help="Without DATASETs: images rendered per training scene."),
    branching: int = typer.Option(10, "--branching", min=2, help="Children per tree node."),
    depth: int = typer.Option(4, "--depth", min=1, help="Tree levels (words: up to branching ** depth)."),
    config: Path | None = typer.Option(None, "--config", help="Settings YAML: its orb section sets the extractor (use the one tracking will use)."),
) -> None:
    """Train a vocabulary (hierarchical k-medians of ORB descriptors, DBoW2's); the one shipped
    with EVP is this command without DATASETs."""
    from evp.cli.progress import progress_of
    from evp.config import load_settings
    from evp.io.vocabulary_files import save_vocabulary
    from evp.vocabulary_training import build_vocabulary, dataset_descriptors, rendered_descriptors

    writable_file(out, example="voc.npz")
    orb = load_settings(config).orb
    with progress_of("extracting ORB features", None, "images") as progress:
        sets, names = dataset_descriptors(sources, every, orb, progress.advance) if sources else rendered_descriptors(frames_per_scene, orb, progress.advance)
    with progress_of(f"clustering {sum(len(d) for d in sets)} descriptors", None, "nodes") as progress:
        counted = [0]

        def clustered(done: int, total: int) -> None:
            progress.total = total
            progress.advance(done - counted[0])
            counted[0] = done

        vocabulary = build_vocabulary(sets, names, branching, depth, orb, clustered)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_vocabulary(vocabulary, out)
    typer.echo(f"{out}: {vocabulary.n_words} words from {len(sets)} images ({vocabulary.notes['descriptors']} descriptors)")


@app.command("info")
def vocabulary_info(path: Path | None = typer.Argument(None, help="Vocabulary file (default: the one shipped with EVP).")) -> None:
    """What a vocabulary is: words, tree shape, what it was trained on."""
    from evp.io.vocabulary_files import default_vocabulary_path, load_vocabulary

    path = path or default_vocabulary_path()
    vocabulary = load_vocabulary(path)
    notes = vocabulary.notes
    typer.echo(f"{path}: {vocabulary.n_words} words, {vocabulary.branching} branches x {vocabulary.depth} levels")
    if notes:
        typer.echo(f"  trained on {notes.get('images', '?')} images, {notes.get('descriptors', '?')} descriptors ({notes.get('built_by', '?')})")
        for source in notes.get("trained_on", []):
            typer.echo(f"    {source}")
