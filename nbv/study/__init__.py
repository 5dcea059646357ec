"""Studies over many runs: evaluation, the experiment and its tables, sweeps, paired statistics, convergence, and the
executors that run jobs.
"""
