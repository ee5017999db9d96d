//! csmetro-camera
