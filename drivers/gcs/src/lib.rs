//! csmetro-gcs
