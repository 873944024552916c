"""Physics by trajectory optimisation: Rempe et al. 2020, "Contact and Human Dynamics from Monocular Video"
(section 3.1 and appendices B-C), with CasADi and IPOPT (MUMPS, exact derivatives).

Use after the offline kinematic stage, the centred contact network and the B.4 refinement
(kinematics/refine.py, which offline PhysCap starts from too):

    refined = refine_kinematics(obs, motion, contacts, settings.fit, settings_trajopt,
                                keep_floor=settings.camera.floor is not None)      # B.4: three-stage fit
    result = run_trajopt(refined.motion.body, refined.motion.qpos, obs.fps, refined.contacts,
                         settings_trajopt, progress=bar, valid=obs.valid)          # 3.1, C: physics
    # refined.motion replaces the kinematic motion downstream (its world sits on the refitted floor);
    # result is shaped like dynamics.stage.PhysicsMotion (qpos, grf, residual, contacts, corrected, qp_failures,
    # seconds) plus converged (T,) and the optimised COM, orientation and contact points; result.summary() is
    # one line for the terminal, result.failed_frames the ranges kept kinematic.

Modules: reduced (B.5 inputs), phases (contact phases), splines (Hermite cubics as sparse sampling maps),
problem (named variable sets, constraint sets and cost terms; IPOPT), formulation (the centroidal problem of
one window), solve (the staged solve), ik (C.4 full-body output through the kinematic fitter), stage
(windows, run_trajopt).
"""

from .stage import TrajoptMotion, WindowReport, run_trajopt

__all__ = ["TrajoptMotion", "WindowReport", "run_trajopt"]
