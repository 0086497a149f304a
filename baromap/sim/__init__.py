"""The embedded default: a simulated building, robot and devices that behave like the real ones.

``building`` holds the floor plans, ``route`` and ``motion`` move the robot through them,
``atmosphere`` and ``bmp280`` turn its height into barometer readings, ``laser`` and
``odometry`` produce what the LMS200 and the P3-AT would report, ``scenario`` ties one seeded
run together, ``record`` writes it to MCAP and ``twins`` serve it on pseudo-terminals in the
devices' real wire protocols.
"""
