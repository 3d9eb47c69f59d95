"""The processes and folders a run lives in: the depth-frame worker pool (framepool), SLAM in a process of its own
(slamproc), what every child process does at birth (childproc) and the output folder's claim, staging and record
(outdir)."""
