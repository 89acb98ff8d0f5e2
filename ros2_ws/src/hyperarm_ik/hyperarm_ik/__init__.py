"""hyperarm_ik: kinematics (pinocchio), IK solvers, IK service node, hybrid force node."""
