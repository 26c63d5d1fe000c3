"""`softjig calibrate-stereo: stereo camera calibration from chessboard/ChArUco views (issue 7).`"""
