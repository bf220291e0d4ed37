"""Recordings and objectives: validated recordings and their files, the paper's splits and
data directory, the objective functions J1, J2, J3 over a recording set, and the parameter sets
named on a command line."""
