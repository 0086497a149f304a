"""The ``baromap`` command: argument parsing and printing, on top of every library layer.

Library packages never parse arguments or print; each module here turns one group of
subcommands into calls of typed library functions and prints what they return.
"""
