"""Recordings and objectives: validated recordings and their files, the paper's splits and
data directory, and the objective functions J1, J2, J3 over a recording set."""
