"""Camera calibration: estimating it from chessboard/ChArUco views, and reading/writing its files."""
