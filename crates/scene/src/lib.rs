//! Reconstruction, cameras, images, 3D points and tracks with typed ids; COLMAP binary/text I/O, PLY export, TUM trajectories
