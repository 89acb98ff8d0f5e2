"""hyperarm_tasks: task sequences (pick-and-place, ...) and the task node."""
