"""Conversions for other ecosystems: ROS 2 bags (:mod:`.ros2`), Open-RMF buildings (:mod:`.rmf`).

Each reads baromap's own outputs (a recording, a build-maps directory) and writes files that the
other ecosystem's own tools read; tests check them with those tools, not with baromap.
"""
