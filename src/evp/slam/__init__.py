"""ORB-SLAM-style monocular SLAM: map, tracking, local mapping, relocalisation."""
