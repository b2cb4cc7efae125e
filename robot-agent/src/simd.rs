//! The agent's hot loops (localizer, signatures), compiled for the CPU's widest vector
//! instructions as well as for the baseline, and run in the best version the
//! CPU has (runtime detection by `pulp`, no `unsafe` here).
//!
//! A release build targets baseline x86-64 (SSE2, 4 lanes of `f32`), so that
//! the agent runs on any robot's computer; the PHAT cross-spectra, sliding
//! maxima, grid sums and beamformer accumulations are plain loops written to
//! vectorize, and with AVX2 they take 8 lanes. A [`Kernel`] is one such
//! piece of work: [`run`] hands it to `pulp`'s dispatch, which calls
//! [`Kernel::run`] inside a function compiled with the detected features.
//! `run` and everything it must take along are `#[inline(always)]`: a call
//! that is not inlined is compiled for the baseline only.
//!
//! Measured on the whole agent (`BENCHMARKS.md`, "Whole process on a file"):
//! the same as building everything with `-C target-cpu=x86-64-v3`, within
//! the machine's noise.

/// One piece of hot work, run by [`run`].
pub(crate) trait Kernel {
    /// What it returns.
    type Output;
    /// Does the work; implementations are `#[inline(always)]`.
    fn run(self) -> Self::Output;
}

struct Dispatch<K>(K);

impl<K: Kernel> pulp::WithSimd for Dispatch<K> {
    type Output = K::Output;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> K::Output {
        self.0.run()
    }
}

/// Runs `kernel` compiled for the best instruction set `arch` found.
#[inline]
pub(crate) fn run<K: Kernel>(arch: pulp::Arch, kernel: K) -> K::Output {
    arch.dispatch(Dispatch(kernel))
}
