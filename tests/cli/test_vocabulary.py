"""``evp vocabulary``: the shipped vocabulary is what the project builds, users can build their
own from recordings, and a bad vocabulary is a clear error before any frame is processed."""

import numpy as np

from evp.config import OrbSettings
from evp.errors import ExitCode
from evp.io.vocabulary_files import default_vocabulary_path, load_vocabulary
from evp.sim.vocabulary_images import TRAINING_SCENES
from evp.vocabulary_training import build_vocabulary, rendered_descriptors
from tests.cli.conftest import evp
from tests.conftest import SAMPLE


def test_the_shipped_vocabulary_is_built_from_evps_renders_by_a_deterministic_build():
    """Nothing is downloaded: the shipped file comes out of ``evp vocabulary build`` from the
    training scenes with today's extractor settings. Rebuilding all of it takes minutes, so
    ``bench/shipped_vocabulary.py`` compares it word for word (run it, and retrain, when the
    extractor or the renderer changes); here the same path on one small scene builds the same
    vocabulary twice."""
    shipped = load_vocabulary(default_vocabulary_path())
    assert shipped.notes["trained_on"] == [scene.label for scene in TRAINING_SCENES]
    assert shipped.notes["orb"] == OrbSettings().model_dump() and shipped.notes["images"] == 40 * len(TRAINING_SCENES)
    room = next(scene for scene in TRAINING_SCENES if scene.scenario == "wheel-robot-room")
    sets, sources = rendered_descriptors(2, OrbSettings(), scenes=(room,))
    assert sources == [room.label] and len(sets) == 2 and min(len(d) for d in sets) > 100
    built, again = (build_vocabulary(sets, sources, 4, 2, OrbSettings()) for _ in range(2))
    assert np.array_equal(built.centres, again.centres) and np.array_equal(built.children, again.children)
    assert np.array_equal(built.idf, again.idf) and built.n_words > 8
    assert built.notes["trained_on"] == [room.label] and built.notes["images"] == 2


def test_a_vocabulary_from_a_recording_and_its_description(tmp_path):
    result = evp("vocabulary", "build", SAMPLE, "--every", "10", "--depth", "2", "--out", tmp_path / "v.npz")
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith(f"{tmp_path / 'v.npz'}: ") and "extracting ORB features: 9 images" in result.stderr  # progress off stdout
    vocabulary = load_vocabulary(tmp_path / "v.npz")
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
