"""Print `name==version` of the real (dist-info) distributions in this environment.

The ROS 2 wheels also install egg-info metadata for each of their Python packages
(rclpy, std_msgs, ...), which `pip freeze` lists but PyPI does not serve; skip those.
"""
import importlib.metadata as md

skip = {"pip", "setuptools", "wheel"}
rows = set()
for dist in md.distributions():
    path = getattr(dist, "_path", None)
    if path is None or not str(path).endswith(".dist-info"):
        continue
    name = dist.metadata["Name"]
    if name and name.lower() not in skip:
        rows.add(f"{name}=={dist.version}")
print("\n".join(sorted(rows, key=str.lower)))
