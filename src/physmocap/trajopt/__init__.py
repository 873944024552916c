"""Physics by trajectory optimisation: Rempe et al. 2020, "Contact and Human Dynamics from Monocular Video"
(section 3.1 and appendices B-C), with CasADi and IPOPT.

    refined = refine_kinematics(obs, motion, contacts, settings.fit, trajopt)   # B.4, three-stage fit
    result = run_trajopt(body, refined.motion.qpos, fps, refined.contacts, trajopt)   # 3.1, C

Modules: reduced (B.5 inputs), phases (contact phases), splines (Hermite cubics), problem (named variable
sets, constraint sets and cost terms; IPOPT), formulation (the centroidal problem of one window), solve (the
staged solve), ik (C.4 full-body output), kinematic (B.4), stage (windows, run_trajopt).
"""

from .kinematic import RefinedKinematics, refine_kinematics
from .stage import TrajoptMotion, WindowReport, run_trajopt

__all__ = ["RefinedKinematics", "TrajoptMotion", "WindowReport", "refine_kinematics", "run_trajopt"]
