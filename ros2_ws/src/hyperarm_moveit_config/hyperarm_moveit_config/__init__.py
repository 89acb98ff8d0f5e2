"""hyperarm's MoveIt 2 configuration, generated from the robot description (docs/moveit.md)."""
