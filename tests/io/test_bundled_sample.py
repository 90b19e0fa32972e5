import numpy as np

from evp.io.registry import open_dataset


def test_bundled_sample_loads_without_shared_data(sample_path):
    dataset = open_dataset(sample_path)
    assert dataset.format == "image-folder"
    assert dataset.num_frames == 87
    assert dataset.camera.fx == 335.419462958
    assert dataset.ground_truth.path_length > 0.9
    frames = list(dataset.frames())
    assert len(frames) == 87 and frames[0].image.shape == (180, 240)
    assert np.all(np.diff([f.timestamp for f in frames]) > 0)
