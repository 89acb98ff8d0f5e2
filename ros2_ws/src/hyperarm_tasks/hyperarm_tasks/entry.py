"""Console-script entry points of the task nodes (see hyperarm_description.launcher)."""
from hyperarm_description.launcher import lazy_main

task_node = lazy_main("hyperarm_tasks.task_node")
task_recorder = lazy_main("hyperarm_tasks.recorder_node")
