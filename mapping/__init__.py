"""The product's core: the pipeline, occupancy grids, map I/O, map comparison and reports."""
