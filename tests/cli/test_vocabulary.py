"""``evp vocabulary``: the shipped vocabulary is what the project builds, users can build their
own from recordings, and a bad vocabulary is a clear error before any frame is processed."""

import numpy as np

from evp.config import OrbSettings
from evp.errors import ExitCode
from evp.vision.vocabulary import Vocabulary, default_vocabulary_path
from evp.vocabulary_training import build_vocabulary, rendered_descriptors
from tests.cli.conftest import evp
from tests.conftest import SAMPLE


def test_the_shipped_vocabulary_is_the_one_evp_builds_from_its_renders():
    """Nothing is downloaded: the shipped file must come out of ``evp vocabulary build`` (the
    renders and the extractor are deterministic). Retrain it when the extractor changes."""
    sets, sources = rendered_descriptors(40, OrbSettings())
    built = build_vocabulary(sets, sources, 10, 4, OrbSettings())
    shipped = Vocabulary.load(default_vocabulary_path())
    assert np.array_equal(built.centres, shipped.centres) and np.array_equal(built.children, shipped.children)
    assert np.allclose(built.idf, shipped.idf)
    assert shipped.notes["trained_on"] == sources and shipped.notes["orb"] == OrbSettings().model_dump()


def test_a_vocabulary_from_a_recording_and_its_description(tmp_path):
    result = evp("vocabulary", "build", SAMPLE, "--every", "10", "--depth", "2", "--out", tmp_path / "v.npz")
    assert result.returncode == 0, result.stderr
    vocabulary = Vocabulary.load(tmp_path / "v.npz")
    assert 10 < vocabulary.n_words <= 100 and vocabulary.notes["images"] == 9  # frames 0, 10, ..., 80
    shown = evp("vocabulary", "info", tmp_path / "v.npz")
    assert shown.returncode == 0 and f"{vocabulary.n_words} words, 10 branches x 2 levels" in shown.stdout
    assert "davis_slider_depth" in shown.stdout
    shipped = evp("vocabulary", "info")
    assert shipped.returncode == 0 and "9999 words" in shipped.stdout and "drone-flight" in shipped.stdout


def test_a_bad_vocabulary_is_a_clear_error_before_any_frame(tmp_path):
    (tmp_path / "broken.npz").write_bytes(b"not a vocabulary")
    (tmp_path / "settings.yaml").write_text(f"slam:\n  vocabulary: {tmp_path / 'broken.npz'}\n")
    result = evp("run", SAMPLE, "--out", tmp_path / "run", "--config", tmp_path / "settings.yaml")
    assert result.returncode == ExitCode.DATA
    assert "broken.npz: not an EVP vocabulary file" in result.stderr
    assert not (tmp_path / "run").exists()
    missing = evp("vocabulary", "build", tmp_path / "nowhere", "--out", tmp_path / "v.npz")
    assert missing.returncode == ExitCode.DATA and missing.stderr.startswith("error:")
    assert not (tmp_path / "v.npz").exists()
