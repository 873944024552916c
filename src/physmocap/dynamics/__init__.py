"""PhysCap's physics stage (Shimada et al. 2020, section 4.3): physcap.py the per-frame tracker (PD targets, the
ground-reaction-force QP, the torque step), balance.py the stationary balance correction, floor.py the floor
refined from contacts, stage.py the stage over a clip (`run_physcap`) and frame by frame (`PhysicsStream`)."""
