"""`softjig sweep-plan: the robot's tilt-sweep poses (issue 7).`"""
