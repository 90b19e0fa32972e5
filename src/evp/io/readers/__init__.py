"""The dataset readers EVP knows.

Auto-detection asks every reader of ``READERS``; a path two of them claim is refused as ambiguous.
``FALLBACK_READERS`` are asked only when none of those claims the path: nearly every dataset
folder also holds trajectory files (its ground truth), which are not a dataset of their own.
"""

from evp.io.readers.cmu_plaza import CmuPlazaReader
from evp.io.readers.comma2k19 import Comma2k19Reader
from evp.io.readers.euroc import EurocReader
from evp.io.readers.exif_photos import ExifPhotoReader
from evp.io.readers.image_folder import ImageFolderReader
from evp.io.readers.kitti import KittiReader
from evp.io.readers.rosbag import RosbagReader
from evp.io.readers.trajectory_files import TrajectoryFilesReader
from evp.io.readers.tuc_labyrinth import TucLabyrinthReader
from evp.io.readers.tum_rgbd import TumRgbdReader
from evp.io.readers.video import VideoReader

READERS = (
    EurocReader(),
    TumRgbdReader(),
    KittiReader(),
    Comma2k19Reader(),
    CmuPlazaReader(),
    TucLabyrinthReader(),
    RosbagReader(),
    VideoReader(),
    ImageFolderReader(),
    ExifPhotoReader(),
)
FALLBACK_READERS = (TrajectoryFilesReader(),)
