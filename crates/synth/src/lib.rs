//! Synthetic textured-room sequences with exact ground truth, written in TUM layout
