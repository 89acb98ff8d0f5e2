"""hyperarm controllers: ROS-free cores (numpy, SI units) and, later, their thin nodes."""
