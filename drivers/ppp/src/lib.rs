//! csmetro-ppp
