"""planar_vo: planar monocular visual odometry (1-point RANSAC on the ground homography)."""
