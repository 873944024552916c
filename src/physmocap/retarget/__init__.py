"""Motion on the user's own character: retargeting with physics on the character's rig (Rempe et al. 2020,
appendix D and E.6). `retarget_result` is the stage; rig.py reads characters, mapping.py maps their bones,
character.py builds their body models, solve.py retargets, writers.py writes the files."""

from .stage import RetargetReport, retarget_result

__all__ = ["RetargetReport", "retarget_result"]
