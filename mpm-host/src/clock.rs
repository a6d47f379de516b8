//! The wall clock as the programs stamp what they write (a checkpoint's header, a run's
//! start and end, an attempt's lost time): seconds since the Unix epoch.

/// Now, in seconds since the Unix epoch (0 if the clock is before it).
pub fn unix_now() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64())
}
