"""`softjig jig fix|release|status: jamming control (issue 8).`"""
