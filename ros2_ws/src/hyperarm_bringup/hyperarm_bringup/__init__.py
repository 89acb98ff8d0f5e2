"""hyperarm bring-up: the `hyperarm` command-line tool, the viewer, launch/config files."""
