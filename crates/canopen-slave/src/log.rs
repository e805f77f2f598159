//! Logging shim in the spirit of embassy's `fmt.rs`.
//!
//! With the `defmt` feature the macros forward to `defmt`; without it they expand to a borrow
//! of every argument, so that host builds neither link a logger nor warn about values that are
//! only computed to be logged.

macro_rules! log_at {
    ($level:ident, $fmt:literal $(, $arg:expr)* $(,)?) => {{
        #[cfg(feature = "defmt")]
        ::defmt::$level!($fmt $(, $arg)*);
        #[cfg(not(feature = "defmt"))]
        {
            let _ = ($(&$arg,)*);
        }
    }};
}

#[allow(unused_macros)]
macro_rules! debug {
    ($($t:tt)*) => { log_at!(debug, $($t)*) };
}

#[allow(unused_macros)]
macro_rules! info {
    ($($t:tt)*) => { log_at!(info, $($t)*) };
}

#[allow(unused_macros)]
macro_rules! warn {
    ($($t:tt)*) => { log_at!(warn, $($t)*) };
}

#[allow(unused_macros)]
macro_rules! error {
    ($($t:tt)*) => { log_at!(error, $($t)*) };
}
