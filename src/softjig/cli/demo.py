"""`softjig demo: the paper's experiment on the simulated jig (issue 4).`"""
