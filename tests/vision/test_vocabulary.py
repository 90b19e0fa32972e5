"""The bag-of-words vocabulary: training recovers clusters, words and weights behave as DBoW2's,
files round-trip and bad ones are refused."""

import numpy as np
import pytest

from evp.errors import EvpError
from evp.io.vocabulary_files import load_vocabulary, save_vocabulary
from evp.vision.vocabulary import Vocabulary, bow_score, train_vocabulary


def _flip_bits(descriptor: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    bits = np.unpackbits(descriptor)
    flip = rng.choice(256, count, replace=False)
    bits[flip] ^= 1
    return np.packbits(bits)


def _clustered(rng, clusters: int, per_cluster: int, noise_bits: int = 12):
    """Descriptors around random centres (far apart: ~128 bits), with each one's cluster."""
    centres = rng.integers(0, 256, (clusters, 32), dtype=np.uint8)
    labels = np.repeat(np.arange(clusters), per_cluster)
    descriptors = np.array([_flip_bits(centres[c], noise_bits, rng) for c in labels])
    return descriptors, labels


def test_training_puts_each_cluster_under_its_own_branch():
    rng = np.random.default_rng(0)
    descriptors, labels = _clustered(rng, 8, 60)
    images = np.array_split(rng.permutation(len(descriptors)), 12)
    vocabulary = train_vocabulary([descriptors[i] for i in images], branching=8, depth=2, seed=1)
    words = vocabulary.words(descriptors)
    # the first level splits by cluster: two descriptors of different clusters never share a word
    for cluster in range(8):
        others = words[labels != cluster]
        assert not np.isin(words[labels == cluster], others).any()
    # new noisy copies of a centre land among that cluster's words
    fresh, fresh_labels = _clustered(np.random.default_rng(0), 8, 60)
    fresh_words = vocabulary.words(np.array([_flip_bits(d, 5, rng) for d in fresh]))
    for cluster in range(8):
        assert np.isin(fresh_words[fresh_labels == cluster], words[labels == cluster]).mean() > 0.9


def test_vectors_are_l1_normalised_and_score_like_dbow2():
    rng = np.random.default_rng(2)
    descriptors, labels = _clustered(rng, 6, 40)
    sets = [descriptors[labels == c] for c in range(6)] + [descriptors]
    vocabulary = train_vocabulary(sets, branching=6, depth=2, seed=0)
    a = vocabulary.transform(descriptors[labels < 3])
    b = vocabulary.transform(descriptors[labels >= 3])
    assert np.isclose(a.weights.sum(), 1.0) and np.all(np.diff(a.words) > 0)
    assert bow_score(a, a) == pytest.approx(1.0)
    assert bow_score(a, b) == pytest.approx(0.0)  # no word in common
    half = vocabulary.transform(descriptors[labels < 2])
    assert 0.2 < bow_score(a, half) < 0.9
    assert bow_score(a, half) == pytest.approx(bow_score(half, a))


def test_a_word_in_every_training_image_carries_no_weight():
    rng = np.random.default_rng(3)
    common = rng.integers(0, 256, 32, dtype=np.uint8)
    rare, _ = _clustered(rng, 4, 10, noise_bits=0)
    sets = [np.vstack([common, rare[i * 10 : (i + 1) * 10]]) for i in range(4)]
    vocabulary = train_vocabulary(sets, branching=5, depth=1, seed=0)
    common_word = vocabulary.words(common[None])[0]
    assert vocabulary.idf[common_word] == 0.0
    assert np.all(vocabulary.idf[np.unique(vocabulary.words(rare))] == pytest.approx(np.log(4)))
    vector = vocabulary.transform(sets[0])
    assert common_word not in vector.words


def test_empty_descriptors_give_an_empty_vector():
    vocabulary = train_vocabulary([np.random.default_rng(4).integers(0, 256, (50, 32), dtype=np.uint8)], branching=4, depth=2)
    empty = vocabulary.transform(np.zeros((0, 32), np.uint8))
    assert len(empty) == 0 and bow_score(empty, empty) == 0.0


def test_a_vocabulary_file_round_trips(tmp_path):
    rng = np.random.default_rng(5)
    descriptors, _ = _clustered(rng, 5, 30)
    vocabulary = train_vocabulary([descriptors[:70], descriptors[70:]], branching=5, depth=3, notes={"source": "test"})
    save_vocabulary(vocabulary, tmp_path / "v.npz")
    loaded = load_vocabulary(tmp_path / "v.npz")
    assert loaded.notes == {"source": "test"} and loaded.n_words == vocabulary.n_words
    assert np.array_equal(loaded.words(descriptors), vocabulary.words(descriptors))


@pytest.mark.parametrize("content", [b"", b"plain text", b"PK\x03\x04cut"], ids=["empty", "text", "truncated zip"])
def test_a_file_that_is_not_a_vocabulary_is_a_clear_error(tmp_path, content):
    (tmp_path / "v.npz").write_bytes(content)
    with pytest.raises(EvpError, match="not an EVP vocabulary file"):
        load_vocabulary(tmp_path / "v.npz")


def test_a_missing_or_corrupt_vocabulary_is_a_clear_error(tmp_path):
    with pytest.raises(EvpError, match="no such vocabulary file"):
        load_vocabulary(tmp_path / "absent.npz")
    vocabulary = train_vocabulary([np.random.default_rng(6).integers(0, 256, (40, 32), dtype=np.uint8)], branching=4, depth=2)
    broken = Vocabulary(4, 2, vocabulary.centres, vocabulary.children + 1000, vocabulary.word_of_node, vocabulary.idf)
    save_vocabulary(broken, tmp_path / "broken.npz")
    with pytest.raises(EvpError, match="corrupt vocabulary"):
        load_vocabulary(tmp_path / "broken.npz")


def test_too_few_descriptors_or_a_degenerate_shape_is_refused():
    with pytest.raises(EvpError, match="cannot train"):
        train_vocabulary([np.zeros((3, 32), np.uint8)], branching=10)
    with pytest.raises(EvpError, match="branching >= 2"):
        train_vocabulary([np.zeros((30, 32), np.uint8)], branching=1)
