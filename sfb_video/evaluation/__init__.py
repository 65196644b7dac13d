"""Measuring the method: synthetic frames with full 3D truth, and the FMO deblurring benchmark.

- ``synthetic``: fit generated frames and score them against their ground truth.
- ``datasets``: the benchmark's datasets (TbD, TbD-3D, Falling Objects) read as its own code does.
- ``synthetic_set``: our fixed set of generated clips, in a layout the evaluation reads.
- ``runner``: run the method per frame and as a warm-started video; tables of the scores.
"""
