//! Optical flow and dynamic masks.
