//! placeholder during build warmup
