"""planar_vo: planar monocular visual odometry (1-point RANSAC on the ground homography).

Importing the package keeps numpy's BLAS to one thread unless the environment already says
how many (``OPENBLAS_NUM_THREADS``): the odometry's linear algebra is small (a few thousand
rows by 15 columns at the most), where BLAS threads only wait for each other, and while other
processes keep the cores busy they spin: an all-four-terrains drive replayed on a 2-core
machine took 12.0 s with one core busy and numpy's default threads, 6.1 s with one (quiet:
5.4 and 4.6 s), the same odometry to the last digit (docs/speed.md). It takes effect only
where numpy is not loaded yet: in the node and the command-line tools, which import this first.
"""

import os

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
