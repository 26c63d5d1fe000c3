"""`softjig live: the live sensing loop (issue 8).`"""
