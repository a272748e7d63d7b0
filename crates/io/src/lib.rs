//! Frame sources: image folders, TUM, EuRoC and KITTI layouts, video files through ffmpeg; frame skip and limit
