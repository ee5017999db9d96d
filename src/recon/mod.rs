//! Reconstruction
