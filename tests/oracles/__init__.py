"""Straightforward implementations of softjig's stages, for tests to check the production code against.

Each oracle does what the production function's docstring says in the plainest way (NumPy, OpenCV's
general detectors, one item at a time), with no concern for speed. They are not part of the package.
"""
