//! Every size a scenario or command line can set is bounded twice: by a sane range (the constants
//! below, checked while the scenario is validated), and by an estimate of the memory the run needs,
//! checked against what the machine has before any work starts
//! ([`crate::pipeline::budget::check_memory`]). A refusal names
//! the number, the estimate and the limit.

/// Largest scenario file read, bytes.
pub const MAX_SCENARIO_BYTES: u64 = 16 << 20;
pub use magcal_report::manifest::MAX_MANIFEST_BYTES;
/// Longest scenario or design name (it names files).
pub const MAX_NAME: usize = 64;
/// Noisy trials per design and noise level.
pub const MAX_TRIALS: usize = 10_000_000;
/// Noise levels of a sweep.
pub const MAX_SIGMAS: usize = 1_000;
/// Levels of execution error (`attitude_sigma_deg`); with the noise levels they share the trial
/// streams' second index (below 2^16).
pub const MAX_ATTITUDE_SIGMAS: usize = 60;
/// Largest execution error, degrees.
pub const MAX_ATTITUDE_SIGMA_DEG: f64 = 30.0;
/// Designs of a scenario.
pub const MAX_DESIGNS: usize = 1_000;
/// Attitudes of one design (and grid points).
pub const MAX_M: usize = 100_000;
/// PSO particles.
pub const MAX_PARTICLES: usize = 100_000;
/// PSO iterations.
pub const MAX_PSO_ITERATIONS: usize = 10_000_000;
/// Starts of the optimum optimiser.
pub const MAX_STARTS: usize = 100_000;
/// Iterations of one start of the optimum optimiser.
pub const MAX_OPTIMUM_ITERATIONS: usize = 1_000_000;
/// Repeated PSO runs.
pub const MAX_PSO_RUNS: usize = 100_000;
/// Step-2 iterations of one calibration.
pub const MAX_STEP2_ITERATIONS: usize = 1_000_000;
/// Candidates of the certificate's grid (about 220 bytes each, twice over at most).
pub const MAX_CERTIFICATE_CANDIDATES: usize = 200_000;
/// See [`MAX_CERTIFICATE_CANDIDATES`]: fewer leave the certificate no grid to start from.
pub const MIN_CERTIFICATE_CANDIDATES: usize = 100;
/// Worker threads.
pub const MAX_THREADS: usize = 256;
/// Smallest positive noise level, nT: 1e-6 nT is still 1e5 times the rounding of a 50,000 nT
/// reading; below it the figures' log axes would span hundreds of decades for nothing.
pub const MIN_SIGMA_NT: f64 = 1e-6;
/// Largest noise level, nT (0.1 T).
pub const MAX_SIGMA_NT: f64 = 1e8;
/// Largest reference field component, nT (0.01 T; the Earth's is below 70,000 nT).
pub const MAX_FIELD_NT: f64 = 1e7;
/// Smallest reference field magnitude, nT.
pub const MIN_FIELD_NT: f64 = 1.0;
/// Scale factors are in `[MIN_SCALE, MAX_SCALE]`.
pub const MIN_SCALE: f64 = 1e-3;
/// See [`MIN_SCALE`].
pub const MAX_SCALE: f64 = 1e3;
/// Largest non-orthogonality angle, degrees. Real sensors are off by a few degrees; near 90 two
/// axes coincide and `K` is singular to working precision.
pub const MAX_PSI_DEG: f64 = 45.0;
/// Largest bias component, nT (0.01 T).
pub const MAX_BIAS_NT: f64 = 1e7;
/// Slack of the explicit attitudes' box check, degrees (1e-8 rad, as the core's check).
pub const BOX_SLACK_DEG: f64 = 5.8e-7;

pub use magcal_logs::limits::*;
