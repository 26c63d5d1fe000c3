"""`softjig fiducials: print the fiducial layout and check it from a stereo pair (issue 7).`"""
