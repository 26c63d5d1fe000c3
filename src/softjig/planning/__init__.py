"""What a robot does with the jig: the paper's tilt-sweep plan and its contact rule (pure functions)."""

from softjig.planning.contact import ContactResult, detect_contact
from softjig.planning.sweep import SweepPose, sweep_plan, sweep_plan_rows

__all__ = ["ContactResult", "SweepPose", "detect_contact", "sweep_plan", "sweep_plan_rows"]
