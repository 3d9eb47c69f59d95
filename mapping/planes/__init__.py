"""`kosmap planes`: FSPF+ (or FSPF) over every depth frame of a log, a folder of depth images or a dataset, with
the thesis's Table 5.2 statistics, plane points and normals (npz, MCAP), processed depth and Fig. 5.2-style
figures. run.py reads as the run's stages; each stage is a module of its own."""
