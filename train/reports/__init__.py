"""Statistics, tables, plots and outputs: what the experiments write and how (atomic
files and output sets that Ctrl-C and SIGTERM wait for).
"""
