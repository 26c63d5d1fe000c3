"""`softjig calibrate: the paper's tilt calibration from a sweep dataset (issue 4).`"""
