//! What one call may ask of the machine, checked before anything is
//! allocated, and the cancellation hook of the long loops.
//!
//! Sizes: a call's output buffers are computed in checked arithmetic from
//! the sizes it is given (n_t x n_cells for `simulate`, the sum of n_t x
//! n_layers over the runs of a sweep) and refused above [`MAX_BYTES`] with an
//! `InvalidInput` error (ValueError in Python) naming the parameters and the
//! bytes requested. The buffers that pass are reserved fallibly
//! ([`zeroed`]), so a failed allocation is an `OutOfMemory` error, never an
//! abort of the process. The grid ([`MAX_CELLS`]), the number of output times
//! ([`MAX_OUTPUT_TIMES`]) and the worker threads of a sweep ([`MAX_THREADS`])
//! have their own ceilings, so that no valid-looking call runs for hours or
//! stalls while the operating system refuses threads.
//!
//! Cancellation: the time stepper (every step attempt), the steady-state
//! solve (every few hundred cells of each shooting pass) and the sweep
//! (before every run, and inside each run's stepper) poll an `AtomicBool`;
//! once it is set they return [`SolveError::Interrupted`]. The core never
//! sets it: the Python bindings do, when Ctrl-C arrives. [`never`] is the
//! flag of callers that do not cancel.

use std::sync::atomic::{AtomicBool, Ordering};

use crate::error::SolveError;

/// Most bytes the output buffers of one call may take: 4 GiB.
pub const MAX_BYTES: usize = 4 << 30;
/// Most finite-volume cells of one run (`simulate`, `steady_state`, sweeps).
pub const MAX_CELLS: usize = 100_000;
/// Most output times of one run.
pub const MAX_OUTPUT_TIMES: usize = 1_000_000;
/// Most RK4 sub-steps per cell of the steady-state solve.
pub const MAX_SUB_STEPS: usize = 4096;
/// Most worker threads of one sweep.
pub const MAX_THREADS: usize = 256;
/// Bytes of one output value (f64).
const F64: usize = std::mem::size_of::<f64>();

static NEVER: AtomicBool = AtomicBool::new(false);

/// A stop flag that is never set, for callers that do not cancel.
pub fn never() -> &'static AtomicBool {
    &NEVER
}

/// `Err(Interrupted)` once `stop` is set.
#[inline]
pub fn check_stop(stop: &AtomicBool) -> Result<(), SolveError> {
    if stop.load(Ordering::Relaxed) {
        Err(SolveError::Interrupted)
    } else {
        Ok(())
    }
}

/// Bytes of `n` f64 values, if that fits in a usize.
pub fn f64_bytes(n: usize) -> Option<usize> {
    n.checked_mul(F64)
}

fn describe(bytes: Option<usize>) -> String {
    match bytes {
        Some(b) => format!("{b} bytes"),
        None => format!("more than {} bytes", usize::MAX),
    }
}

/// Refuse a buffer of `dims` (name, size) f64 values above [`MAX_BYTES`];
/// returns its length in values. `what` names the buffer in the message.
pub fn check_buffer(what: &str, dims: &[(&str, usize)]) -> Result<usize, SolveError> {
    let len = dims
        .iter()
        .try_fold(1usize, |acc, &(_, n)| acc.checked_mul(n));
    let bytes = len.and_then(f64_bytes);
    match (len, bytes) {
        (Some(len), Some(b)) if b <= MAX_BYTES => Ok(len),
        _ => {
            let sizes: Vec<String> = dims.iter().map(|(n, v)| format!("{n} = {v}")).collect();
            Err(SolveError::InvalidInput(format!(
                "{what} ({} x 8 bytes) would need {}, more than the {MAX_BYTES} bytes (4 GiB) \
                 one call may allocate: lower {}",
                sizes.join(" x "),
                describe(bytes),
                dims.iter().map(|d| d.0).collect::<Vec<_>>().join(" or "),
            )))
        }
    }
}

/// Refuse a grid of more than [`MAX_CELLS`] cells, naming `n_cells`.
pub fn check_cells(n_cells: usize) -> Result<(), SolveError> {
    if n_cells > MAX_CELLS {
        return Err(SolveError::InvalidInput(format!(
            "n_cells = {n_cells} is out of range: must be <= {MAX_CELLS} \
             (about {} of workspace)",
            describe(n_cells.checked_mul(24 * F64))
        )));
    }
    Ok(())
}

/// Refuse more than [`MAX_OUTPUT_TIMES`] output times; `name` is the array's name.
pub fn check_output_times(name: &str, n_t: usize) -> Result<(), SolveError> {
    if n_t > MAX_OUTPUT_TIMES {
        return Err(SolveError::InvalidInput(format!(
            "{name} has {n_t} output times: at most {MAX_OUTPUT_TIMES} per run \
             ({} for their times alone); use a longer output step",
            describe(f64_bytes(n_t))
        )));
    }
    Ok(())
}

/// Refuse a thread count of 0 or above [`MAX_THREADS`], naming `threads`.
pub fn check_threads(threads: usize) -> Result<(), SolveError> {
    if threads == 0 || threads > MAX_THREADS {
        return Err(SolveError::InvalidInput(format!(
            "threads = {threads} is out of range: must be in 1..={MAX_THREADS}"
        )));
    }
    Ok(())
}

/// An empty vector with room for `len` values, reserved fallibly: a refused
/// allocation is an `OutOfMemory` error naming `what` and the bytes, not an
/// abort. Nothing is written, so the pages are touched only as it is filled.
pub fn reserved(len: usize, what: &str) -> Result<Vec<f64>, SolveError> {
    let mut v: Vec<f64> = Vec::new();
    v.try_reserve_exact(len).map_err(|e| {
        SolveError::OutOfMemory(format!(
            "cannot allocate {} for {what}: {e}",
            describe(f64_bytes(len))
        ))
    })?;
    Ok(v)
}

/// `len` zeros, reserved fallibly as [`reserved`].
pub fn zeroed(len: usize, what: &str) -> Result<Vec<f64>, SolveError> {
    let mut v = reserved(len, what)?;
    v.resize(len, 0.0);
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buffer_check_names_the_sizes_and_bytes() {
        assert_eq!(
            check_buffer("c", &[("t", 1801), ("n_cells", 180)]),
            Ok(1801 * 180)
        );
        let e = check_buffer("c", &[("t", 1801), ("n_cells", 2_000_000)]).unwrap_err();
        assert!(e.is_input_error());
        let m = e.to_string();
        assert!(m.contains("28816000000 bytes"), "{m}");
        assert!(
            m.contains("n_cells = 2000000") && m.contains("t = 1801"),
            "{m}"
        );
        // exactly at the ceiling passes, one value more does not
        assert!(check_buffer("x", &[("n", MAX_BYTES / 8)]).is_ok());
        assert!(check_buffer("x", &[("n", MAX_BYTES / 8 + 1)]).is_err());
    }

    #[test]
    fn buffer_check_survives_overflow() {
        let e = check_buffer("c", &[("t", usize::MAX), ("n_cells", 3)]).unwrap_err();
        assert!(e.to_string().contains("more than"), "{e}");
        let e = check_buffer("c", &[("t", usize::MAX / 4), ("n_cells", 1)]).unwrap_err();
        assert!(e.to_string().contains("more than"), "{e}");
    }

    #[test]
    fn cells_times_and_threads_have_ceilings() {
        assert!(check_cells(MAX_CELLS).is_ok());
        assert!(check_cells(MAX_CELLS + 1)
            .unwrap_err()
            .to_string()
            .contains("n_cells = 100001"));
        assert!(check_output_times("t", MAX_OUTPUT_TIMES).is_ok());
        assert!(check_output_times("t", MAX_OUTPUT_TIMES + 1)
            .unwrap_err()
            .to_string()
            .starts_with("t has 1000001 output times"));
        assert!(check_threads(1).is_ok() && check_threads(MAX_THREADS).is_ok());
        for bad in [0, MAX_THREADS + 1, 10_000] {
            assert!(check_threads(bad)
                .unwrap_err()
                .to_string()
                .contains(&format!("threads = {bad}")));
        }
    }

    #[test]
    fn a_refused_allocation_is_an_error() {
        // more than isize::MAX bytes: try_reserve refuses without asking the allocator
        let e = zeroed(usize::MAX / 4, "the test").unwrap_err();
        assert!(matches!(e, SolveError::OutOfMemory(_)), "{e:?}");
        assert!(!e.is_input_error());
        assert_eq!(zeroed(3, "x").unwrap(), vec![0.0; 3]);
        let e = reserved(usize::MAX / 4, "the test").unwrap_err();
        assert!(matches!(e, SolveError::OutOfMemory(_)), "{e:?}");
        let v = reserved(5, "x").unwrap();
        assert!(v.is_empty() && v.capacity() >= 5);
    }

    #[test]
    fn stop_flag() {
        assert!(check_stop(never()).is_ok());
        let s = AtomicBool::new(true);
        assert_eq!(check_stop(&s), Err(SolveError::Interrupted));
    }
}
