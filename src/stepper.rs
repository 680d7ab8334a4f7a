//! Implicit, adaptive, error-controlled time integration.
//!
//! An L-stable, stiffly accurate ESDIRK of order 3 with an embedded order-2
//! solution: the implicit part of Kennedy & Carpenter's ARK3(2)4L[2]SA. All
//! three implicit stages share the diagonal coefficient gamma, so one
//! factorisation of M = I - h gamma J serves the whole step, and the first
//! stage is the last stage of the previous step (FSAL). Third order cut the
//! step count by ~2x against TR-BDF2 at equal layer-map accuracy. The
//! fourth- and fifth-order members of the family (ARK4(3)6L[2]SA and
//! ARK5(4)8L[2]SA, `Scheme::Esdirk4` / `Esdirk5`, through `integrate_scheme`)
//! take fewer steps at equal accuracy but more stages per step
//! (`examples/work_precision.rs`, BENCHMARKS.md). At the 1e-3 the layer maps
//! need, ESDIRK3 is the fastest on G-PP and ESDIRK4 on the hardest case
//! (S-PP, c0 = 0.9); as a default, ESDIRK4 at rtol 1e-4 is 12 % faster but
//! misses 1e-3 on 4 of 48 cases drawn over the physical ranges
//! (`examples/default_survey.rs`), so ESDIRK3 stays the default.
//!
//! Each stage is solved by simplified Newton with the tridiagonal Jacobian of
//! `flux::Operator` (upwind + diffusion part). The overburden pressure is kept
//! *implicit in the residual* but left out of the Jacobian: carrying the face
//! pressures as extra unknowns (an exact, banded Jacobian factorised with
//! faer's sparse LU, `pressure_coupled.rs`, behind the `pressure-coupled`
//! cargo feature) reaches the same converged
//! solution but costs more per step than the Newton iterations it saves
//! (measured in `benches/solver.rs`, recorded in BENCHMARKS.md), so the fast
//! path lags only the Jacobian, never P itself.
//!
//! Conservation: every column of the approximate Jacobian sums to zero, so
//! every Newton update, stage and step keeps the depth integral of c to
//! round-off. Outputs come from cubic Hermite interpolation between steps
//! (which also conserves mass, since the derivatives sum to zero).
//!
//! Given tangents (`integrate_core` with a `Sensitivities`), each accepted step
//! is then differentiated along them with the exact Jacobian (`sensitivity.rs`).

use std::sync::atomic::AtomicBool;

use crate::error::SolveError;
use crate::flux::Operator;
use crate::layers::LayerMap;
use crate::limits;
use crate::model::initial_condition;
use crate::params::Params;
use crate::sensitivity::Sensitivities;
use crate::tridiag::TridiagLu;

/// Error tolerances of the step-size control (weighted RMS norm).
#[derive(Clone, Copy, Debug)]
pub struct Tolerances {
    pub rtol: f64,
    pub atol: f64,
}

impl Default for Tolerances {
    fn default() -> Self {
        // Meets 1e-3 on the 15-layer maps over the physical ranges (tests).
        Tolerances {
            rtol: 3e-5,
            atol: 3e-6,
        }
    }
}

/// Counters of one run.
#[derive(Clone, Copy, Debug, Default)]
pub struct Stats {
    pub steps: usize,
    pub rejected: usize,
    pub newton_iters: usize,
    pub newton_failures: usize,
    pub rhs_evals: usize,
    pub jacobians: usize,
    pub clipped: usize,
    /// Largest amount of c clipped from one cell (states and outputs).
    pub max_clip: f64,
}

/// Butcher tableau of a stiffly accurate ESDIRK (explicit first stage, one
/// diagonal coefficient gamma, last row = weights, last node = 1): `a` holds
/// the lower triangle by rows, diagonal included (row 0 is the explicit stage).
pub struct Tableau {
    pub name: &'static str,
    pub gamma: f64,
    pub a: &'static [&'static [f64]],
    pub b: &'static [f64],
    pub b_hat: &'static [f64],
    pub c: &'static [f64],
    /// Order q of the embedded solution: the error estimate is O(h^(q+1)),
    /// so the step-size control uses the exponent 1 / (q + 1).
    pub embedded_order: u32,
}

impl Tableau {
    pub fn stages(&self) -> usize {
        self.b.len()
    }
}

const G: f64 = 1767732205903.0 / 4055673282236.0;

/// ARK3(2)4L[2]SA, ESDIRK part (Kennedy & Carpenter 2003), as SUNDIALS
/// ARKODE tabulates it. The default.
pub const ESDIRK3: Tableau = Tableau {
    name: "esdirk3",
    gamma: G,
    a: &[
        &[0.0],
        &[G, G],
        &[
            2746238789719.0 / 10658868560708.0,
            -640167445237.0 / 6845629431997.0,
            G,
        ],
        &[
            1471266399579.0 / 7840856788654.0,
            -4482444167858.0 / 7529755066697.0,
            11266239266428.0 / 11593286722821.0,
            G,
        ],
    ],
    b: &[
        1471266399579.0 / 7840856788654.0,
        -4482444167858.0 / 7529755066697.0,
        11266239266428.0 / 11593286722821.0,
        G,
    ],
    b_hat: &[
        2756255671327.0 / 12835298489170.0,
        -10771552573575.0 / 22201958757719.0,
        9247589265047.0 / 10645013368117.0,
        2193209047091.0 / 5459859503100.0,
    ],
    c: &[0.0, 1767732205903.0 / 2027836641118.0, 3.0 / 5.0, 1.0],
    embedded_order: 2,
};

/// ARK4(3)6L[2]SA, ESDIRK part (Kennedy & Carpenter 2003; SUNDIALS'
/// ARK436L2SA_DIRK_6_3_4): order 4 with an order-3 embedding, six stages.
pub const ESDIRK4: Tableau = Tableau {
    name: "esdirk4",
    gamma: 0.25,
    a: &[
        &[0.0],
        &[0.25, 0.25],
        &[8611.0 / 62500.0, -1743.0 / 31250.0, 0.25],
        &[
            5012029.0 / 34652500.0,
            -654441.0 / 2922500.0,
            174375.0 / 388108.0,
            0.25,
        ],
        &[
            15267082809.0 / 155376265600.0,
            -71443401.0 / 120774400.0,
            730878875.0 / 902184768.0,
            2285395.0 / 8070912.0,
            0.25,
        ],
        &[
            82889.0 / 524892.0,
            0.0,
            15625.0 / 83664.0,
            69875.0 / 102672.0,
            -2260.0 / 8211.0,
            0.25,
        ],
    ],
    b: &[
        82889.0 / 524892.0,
        0.0,
        15625.0 / 83664.0,
        69875.0 / 102672.0,
        -2260.0 / 8211.0,
        0.25,
    ],
    b_hat: &[
        4586570599.0 / 29645900160.0,
        0.0,
        178811875.0 / 945068544.0,
        814220225.0 / 1159782912.0,
        -3700637.0 / 11593932.0,
        61727.0 / 225920.0,
    ],
    c: &[0.0, 0.5, 83.0 / 250.0, 31.0 / 50.0, 17.0 / 20.0, 1.0],
    embedded_order: 3,
};

/// ARK5(4)8L[2]SA, ESDIRK part (Kennedy & Carpenter 2003; SUNDIALS'
/// ARK548L2SA_DIRK_8_4_5): order 5 with an order-4 embedding, eight stages.
pub const ESDIRK5: Tableau = Tableau {
    name: "esdirk5",
    gamma: 41.0 / 200.0,
    a: &[
        &[0.0],
        &[41.0 / 200.0, 41.0 / 200.0],
        &[
            41.0 / 400.0,
            -567603406766.0 / 11931857230679.0,
            41.0 / 200.0,
        ],
        &[
            683785636431.0 / 9252920307686.0,
            0.0,
            -110385047103.0 / 1367015193373.0,
            41.0 / 200.0,
        ],
        &[
            3016520224154.0 / 10081342136671.0,
            0.0,
            30586259806659.0 / 12414158314087.0,
            -22760509404356.0 / 11113319521817.0,
            41.0 / 200.0,
        ],
        &[
            218866479029.0 / 1489978393911.0,
            0.0,
            638256894668.0 / 5436446318841.0,
            -1179710474555.0 / 5321154724896.0,
            -60928119172.0 / 8023461067671.0,
            41.0 / 200.0,
        ],
        &[
            1020004230633.0 / 5715676835656.0,
            0.0,
            25762820946817.0 / 25263940353407.0,
            -2161375909145.0 / 9755907335909.0,
            -211217309593.0 / 5846859502534.0,
            -4269925059573.0 / 7827059040749.0,
            41.0 / 200.0,
        ],
        &[
            -872700587467.0 / 9133579230613.0,
            0.0,
            0.0,
            22348218063261.0 / 9555858737531.0,
            -1143369518992.0 / 8141816002931.0,
            -39379526789629.0 / 19018526304540.0,
            32727382324388.0 / 42900044865799.0,
            41.0 / 200.0,
        ],
    ],
    b: &[
        -872700587467.0 / 9133579230613.0,
        0.0,
        0.0,
        22348218063261.0 / 9555858737531.0,
        -1143369518992.0 / 8141816002931.0,
        -39379526789629.0 / 19018526304540.0,
        32727382324388.0 / 42900044865799.0,
        41.0 / 200.0,
    ],
    b_hat: &[
        -975461918565.0 / 9796059967033.0,
        0.0,
        0.0,
        78070527104295.0 / 32432590147079.0,
        -548382580838.0 / 3424219808633.0,
        -33438840321285.0 / 15594753105479.0,
        3629800801594.0 / 4656183773603.0,
        4035322873751.0 / 18575991585200.0,
    ],
    c: &[
        0.0,
        41.0 / 100.0,
        2935347310677.0 / 11292855782101.0,
        1426016391358.0 / 7196633302097.0,
        92.0 / 100.0,
        24.0 / 100.0,
        3.0 / 5.0,
        1.0,
    ],
    embedded_order: 4,
};

/// The time-stepping schemes: ESDIRK3 is the default (issue 15's
/// work-precision comparison, BENCHMARKS.md, says why).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Scheme {
    #[default]
    Esdirk3,
    Esdirk4,
    Esdirk5,
}

impl Scheme {
    pub fn tableau(self) -> &'static Tableau {
        match self {
            Scheme::Esdirk3 => &ESDIRK3,
            Scheme::Esdirk4 => &ESDIRK4,
            Scheme::Esdirk5 => &ESDIRK5,
        }
    }

    /// The scheme named `name` (`esdirk3`, `esdirk4`, `esdirk5`).
    pub fn from_name(name: &str) -> Result<Scheme, SolveError> {
        [Scheme::Esdirk3, Scheme::Esdirk4, Scheme::Esdirk5]
            .into_iter()
            .find(|s| s.tableau().name == name)
            .ok_or_else(|| {
                SolveError::InvalidInput(format!(
                    "scheme = {name:?} is not one of esdirk3, esdirk4, esdirk5"
                ))
            })
    }
}

const NEWTON_MAX: usize = 8;
const NEWTON_KAPPA: f64 = 0.1;
const MIN_STEP: f64 = 1e-10;
const MAX_STEPS: usize = 1_000_000;

/// The Newton iteration matrix M = I - s J of a step and its solver.
pub trait NewtonMatrix {
    /// Rebuild J from the face data of the operator's last `rhs` call (at
    /// approximately the state `c`).
    fn update(&mut self, op: &Operator, c: &[f64]);
    /// Factorise M = I - s J; false if it is singular.
    fn factor(&mut self, s: f64) -> bool;
    /// Solve M x = b in place.
    fn solve(&mut self, x: &mut [f64]);
}

/// The default: tridiagonal J (pressure lagged in the Jacobian only),
/// Thomas algorithm.
pub struct Tridiagonal {
    sub: Vec<f64>,
    diag: Vec<f64>,
    sup: Vec<f64>,
    lu: TridiagLu,
}

impl Tridiagonal {
    pub fn new(n: usize) -> Self {
        Tridiagonal {
            sub: vec![0.0; n],
            diag: vec![0.0; n],
            sup: vec![0.0; n],
            lu: TridiagLu::new(n),
        }
    }
}

impl NewtonMatrix for Tridiagonal {
    fn update(&mut self, op: &Operator, _c: &[f64]) {
        op.tridiagonal_jacobian(&mut self.sub, &mut self.diag, &mut self.sup);
    }
    fn factor(&mut self, s: f64) -> bool {
        self.lu.factor_shifted(s, &self.sub, &self.diag, &self.sup)
    }
    fn solve(&mut self, x: &mut [f64]) {
        self.lu.solve(x);
    }
}

/// Where the stepper writes the profile at each output time: it fills the
/// buffer `profile(k)` returns (in place, no copy), then calls `done(k)`.
pub trait Output {
    fn profile(&mut self, k: usize) -> &mut [f64];
    fn done(&mut self, _k: usize) {}
    /// An output that keeps only layer means names its layer map here; the
    /// stepper then reduces each step's interpolant once and writes the layer
    /// values of every output time in that step to `layer_row(k)` directly.
    fn layer_map(&self) -> Option<&LayerMap> {
        None
    }
    fn layer_row(&mut self, _k: usize) -> &mut [f64] {
        unreachable!("layer_row without a layer_map")
    }
}

/// Layer means (n_t * n_layers, row-major) at the output times, without the
/// field: what every comparison with a camera's map needs.
pub struct LayerOutput {
    map: LayerMap,
    /// One profile, for the steps whose interpolant may leave [0, 1] (those
    /// are evaluated cell by cell, clipped, then reduced).
    buf: Vec<f64>,
    pub layers: Vec<f64>,
}

impl LayerOutput {
    /// The output of one run: n_t times of n_layers layers over n_cells cells,
    /// its size checked before it is allocated.
    pub fn for_run(n_cells: usize, n_t: usize, n_layers: usize) -> Result<Self, SolveError> {
        let len =
            limits::check_buffer("the layer map", &[("len(t)", n_t), ("n_layers", n_layers)])?;
        LayerOutput::new(
            LayerMap::new(n_cells, n_layers),
            n_cells,
            limits::zeroed(len, "the layer map")?,
        )
    }

    pub fn new(map: LayerMap, n_cells: usize, layers: Vec<f64>) -> Result<Self, SolveError> {
        Ok(LayerOutput {
            map,
            buf: limits::zeroed(n_cells, "a profile")?,
            layers,
        })
    }
}

impl Output for LayerOutput {
    fn profile(&mut self, _k: usize) -> &mut [f64] {
        &mut self.buf
    }
    fn done(&mut self, k: usize) {
        let n = self.map.n_layers();
        self.map
            .apply(&self.buf, &mut self.layers[k * n..(k + 1) * n]);
    }
    fn layer_map(&self) -> Option<&LayerMap> {
        Some(&self.map)
    }
    fn layer_row(&mut self, k: usize) -> &mut [f64] {
        let n = self.map.n_layers();
        &mut self.layers[k * n..(k + 1) * n]
    }
}

/// Adapter: hand each profile to a closure (used for layer means).
struct CallbackOutput<F: FnMut(usize, &[f64])> {
    buf: Vec<f64>,
    sink: F,
}

impl<F: FnMut(usize, &[f64])> Output for CallbackOutput<F> {
    fn profile(&mut self, _k: usize) -> &mut [f64] {
        &mut self.buf
    }
    fn done(&mut self, k: usize) {
        (self.sink)(k, &self.buf);
    }
}

/// Full profiles, (n_t * n_cells) row-major, grown row by row as the stepper
/// writes them in time order, within capacity reserved for every row. Zeroing
/// the whole field first would touch every page twice and, for the largest
/// runs (1.4 GB), hold off a stop request for a second before the first step.
struct FullOutput {
    n: usize,
    c: Vec<f64>,
}

impl Output for FullOutput {
    fn profile(&mut self, k: usize) -> &mut [f64] {
        let end = (k + 1) * self.n;
        if self.c.len() < end {
            self.c.resize(end, 0.0); // within the reserved capacity: no reallocation
        }
        &mut self.c[k * self.n..end]
    }
}

/// Validate what a run is given besides the parameters.
pub fn validate_run(n_cells: usize, t_out: &[f64], tol: &Tolerances) -> Result<(), SolveError> {
    if n_cells < 15 {
        return Err(SolveError::InvalidInput(format!(
            "n_cells = {n_cells} is out of range: must be >= 15 (one cell per layer at least)"
        )));
    }
    limits::check_cells(n_cells)?;
    for (name, v) in [("rtol", tol.rtol), ("atol", tol.atol)] {
        if !(v.is_finite() && v > 0.0 && v < 1.0) {
            return Err(SolveError::InvalidInput(format!(
                "{name} = {v} is out of range: must be in (0, 1)"
            )));
        }
    }
    if t_out.is_empty() {
        return Err(SolveError::InvalidInput(
            "t is empty: give at least one output time".into(),
        ));
    }
    limits::check_output_times("t", t_out.len())?;
    for (i, &t) in t_out.iter().enumerate() {
        if !t.is_finite() || t < 0.0 {
            return Err(SolveError::InvalidInput(format!(
                "t[{i}] = {t} is out of range: times must be finite and >= 0 s"
            )));
        }
        if i > 0 && t <= t_out[i - 1] {
            return Err(SolveError::InvalidInput(format!(
                "t is not strictly increasing: t[{}] = {} >= t[{i}] = {t}",
                i - 1,
                t_out[i - 1]
            )));
        }
    }
    Ok(())
}

/// Clip c to [0, 1] and hand the clipped mass back proportionally to the
/// cells with room, so the depth integral is unchanged. Returns the largest
/// amount clipped from one cell (0 if none), reported in `Stats::max_clip`.
pub fn enforce_bounds(c: &mut [f64]) -> f64 {
    let mut added = 0.0; // mass created by lifting negatives to 0
    let mut removed = 0.0; // mass destroyed by lowering values to 1
    let mut largest: f64 = 0.0;
    for v in c.iter_mut() {
        if *v < 0.0 {
            added -= *v;
            largest = largest.max(-*v);
            *v = 0.0;
        } else if *v > 1.0 {
            removed += *v - 1.0;
            largest = largest.max(*v - 1.0);
            *v = 1.0;
        }
    }
    if added == 0.0 && removed == 0.0 {
        return 0.0;
    }
    let net = added - removed; // > 0: take mass out; < 0: put mass in
    if net > 0.0 {
        let total: f64 = c.iter().sum();
        if total > 0.0 {
            let f = net / total;
            c.iter_mut().for_each(|v| *v -= f * *v);
        }
    } else if net < 0.0 {
        let room: f64 = c.iter().map(|v| 1.0 - v).sum();
        if room > 0.0 {
            let f = -net / room;
            c.iter_mut().for_each(|v| *v += f * (1.0 - *v));
        }
    }
    largest
}

/// Weighted RMS norm with weights 1 / (atol + rtol |y|).
#[inline]
fn wrms(x: &[f64], scale: &[f64]) -> f64 {
    let s: f64 = x.iter().zip(scale).map(|(v, s)| (v / s) * (v / s)).sum();
    (s / x.len() as f64).sqrt()
}

/// Run state and workspace, allocated once per run.
struct Work<M: NewtonMatrix> {
    y: Vec<f64>,
    /// stage derivatives; k[0] = f(t, y), k[last] = f(t + h, y_new)
    k: Vec<Vec<f64>>,
    y_new: Vec<f64>,
    base: Vec<f64>,
    fy: Vec<f64>,
    delta: Vec<f64>,
    err: Vec<f64>,
    scale: Vec<f64>,
    herm: [Vec<f64>; 3],
    /// start and size of the last accepted step (for the stage predictor)
    y_prev: Vec<f64>,
    h_prev: Option<f64>,
    stage1: Vec<f64>,
    /// layer means of the interpolant's coefficients (4 x n_layers), for layer outputs
    layer_coef: Vec<f64>,
    matrix: M,
    eta: f64,
}

impl<M: NewtonMatrix> Work<M> {
    fn new(n: usize, matrix: M, stages: usize) -> Self {
        let z = || vec![0.0; n];
        Work {
            y: z(),
            k: (0..stages).map(|_| z()).collect(),
            y_new: z(),
            base: z(),
            fy: z(),
            delta: z(),
            err: z(),
            scale: z(),
            herm: [z(), z(), z()],
            y_prev: z(),
            h_prev: None,
            stage1: z(),
            layer_coef: Vec::new(),
            matrix,
            eta: 1.0,
        }
    }
}

enum Attempt {
    Accepted(f64),
    ErrorTooLarge(f64),
    NewtonFailed(&'static str),
}

/// Simplified Newton for Y - hd f(t, Y) = base; `y` holds the guess on entry
/// and the solution on exit, `k` receives the implied stage derivative.
#[allow(clippy::too_many_arguments)]
fn solve_stage(
    op: &mut Operator,
    t: f64,
    hd: f64,
    base: &[f64],
    y: &mut [f64],
    k: &mut [f64],
    fy: &mut [f64],
    delta: &mut [f64],
    lu: &mut impl NewtonMatrix,
    scale: &[f64],
    eta: &mut f64,
    stats: &mut Stats,
) -> Result<(), &'static str> {
    let mut prev = f64::INFINITY;
    for it in 0..NEWTON_MAX {
        op.rhs(t, y, fy);
        for i in 0..y.len() {
            delta[i] = base[i] + hd * fy[i] - y[i];
        }
        lu.solve(delta);
        y.iter_mut().zip(delta.iter()).for_each(|(a, b)| *a += b);
        stats.newton_iters += 1;
        let norm = wrms(delta, scale);
        if !norm.is_finite() {
            return Err("Newton iterate is not finite");
        }
        if it > 0 {
            let theta = norm / prev;
            if theta >= 0.99 {
                return Err("Newton iteration diverged");
            }
            *eta = theta / (1.0 - theta);
        } else {
            *eta = eta.max(f64::EPSILON).powf(0.8);
        }
        if *eta * norm <= NEWTON_KAPPA || norm <= 1e-12 {
            let inv = 1.0 / hd;
            for i in 0..y.len() {
                k[i] = (y[i] - base[i]) * inv;
            }
            return Ok(());
        }
        prev = norm;
    }
    Err("Newton iteration did not converge")
}

/// Newton's starting guess for stage s. Good guesses save iterations: the
/// first implicit stage extrapolates the previous step's Hermite cubic (when
/// there is one), the later stages interpolate the cubic through (y, k0) and
/// (Y_1, k1), which already spans most of the step (c_1 = 0.87).
fn predict_stage<M: NewtonMatrix>(w: &mut Work<M>, s: usize, h: f64, tab: &Tableau) {
    let n = w.y.len();
    if s == 1 {
        if let Some(h_prev) = w.h_prev {
            let theta = 1.0 + tab.c[1] * h / h_prev;
            hermite_eval(&mut w.y_new, &w.y_prev, &w.herm, theta);
            w.stage1.copy_from_slice(&w.y_new);
        } else {
            for i in 0..n {
                w.y_new[i] = w.base[i] + h * tab.gamma * w.k[0][i];
            }
        }
        return;
    }
    if s == 2 {
        // Y_1 is in y_new after stage 1: keep it for the interpolant
        w.stage1.copy_from_slice(&w.y_new);
    }
    let span = tab.c[1] * h;
    let theta = tab.c[s] / tab.c[1];
    let (t2, t3) = (theta * theta, theta * theta * theta);
    let (h00, h10, h01, h11) = (
        2.0 * t3 - 3.0 * t2 + 1.0,
        t3 - 2.0 * t2 + theta,
        -2.0 * t3 + 3.0 * t2,
        t3 - t2,
    );
    for i in 0..n {
        w.y_new[i] =
            h00 * w.y[i] + h10 * span * w.k[0][i] + h01 * w.stage1[i] + h11 * span * w.k[1][i];
    }
}

/// One ESDIRK step of size h from (t, w.y) with w.k[0] = f(t, y). On success
/// w.y_new / w.k[last] hold the new state and its derivative.
#[allow(clippy::too_many_arguments)]
fn attempt_step<M: NewtonMatrix>(
    op: &mut Operator,
    w: &mut Work<M>,
    tab: &Tableau,
    t: f64,
    h: f64,
    tol: &Tolerances,
    fresh_jac: bool,
    stats: &mut Stats,
) -> Attempt {
    let n = w.y.len();
    let hg = h * tab.gamma;
    for i in 0..n {
        w.scale[i] = tol.atol + tol.rtol * w.y[i].abs();
    }
    for s in 1..tab.stages() {
        // explicit part of the stage
        for i in 0..n {
            let mut acc = w.y[i];
            for (j, kj) in w.k[..s].iter().enumerate() {
                acc += h * tab.a[s][j] * kj[i];
            }
            w.base[i] = acc;
        }
        predict_stage(w, s, h, tab);
        let rest = &mut w.k[s..];
        let ts = t + tab.c[s] * h;
        if s == 1 {
            if fresh_jac {
                // The face data of the last rhs call (the previous step's
                // final Newton iterate, i.e. ~y) give the Jacobian for free.
                w.matrix.update(op, &w.y);
                stats.jacobians += 1;
            }
            if !w.matrix.factor(hg) {
                return Attempt::NewtonFailed("iteration matrix is singular");
            }
        }
        if let Err(e) = solve_stage(
            op,
            ts,
            hg,
            &w.base,
            &mut w.y_new,
            &mut rest[0],
            &mut w.fy,
            &mut w.delta,
            &mut w.matrix,
            &w.scale,
            &mut w.eta,
            stats,
        ) {
            return Attempt::NewtonFailed(e);
        }
    }
    // embedded error, filtered through (I - h gamma J)^-1 (Hosea & Shampine)
    for i in 0..n {
        let mut e = 0.0;
        for (j, kj) in w.k.iter().enumerate() {
            e += (tab.b[j] - tab.b_hat[j]) * kj[i];
        }
        w.err[i] = h * e;
        w.scale[i] = tol.atol + tol.rtol * w.y[i].abs().max(w.y_new[i].abs());
    }
    w.matrix.solve(&mut w.err);
    let e = wrms(&w.err, &w.scale);
    if e.is_finite() && e <= 1.0 {
        Attempt::Accepted(e)
    } else {
        Attempt::ErrorTooLarge(if e.is_finite() { e } else { 1e10 })
    }
}

/// The last stage's derivative once its state has been clipped to [0, 1]:
/// the Newton-consistent k (Y = base + h gamma k) moved by what the clip moved
/// Y, (clipped - unclipped) / (h gamma). It sums to zero like the clip
/// (mass is kept), and it is the slope the Hermite outputs of this step and
/// the next step's explicit stage use.
///
/// Not f(Y) evaluated afresh, as before: at a stiff steady state the steps
/// grow to hundreds of seconds, the stiff modes of f(Y) are the Newton
/// iteration's leftover times their eigenvalues, and h f(Y) bent the
/// outputs of the bottom cells by up to 0.05 mid-step whenever a clip of
/// 1e-12 elsewhere triggered the re-evaluation (2.6e-3 in a layer mean at
/// the default tolerances; `cargo run --release --example default_survey -- 48`).
fn clipped_derivative(k: &mut [f64], clipped: &[f64], unclipped: &[f64], h_gamma: f64) {
    let inv = 1.0 / h_gamma;
    for ((ki, c), u) in k.iter_mut().zip(clipped).zip(unclipped) {
        *ki += (c - u) * inv;
    }
}

/// Cubic Hermite interpolant on [t0, t0 + h] written as
/// y0 + theta (d1 + theta (d2 + theta d3)), coefficients computed once per step.
fn hermite_coefficients(
    d: &mut [Vec<f64>; 3],
    y0: &[f64],
    f0: &[f64],
    y1: &[f64],
    f1: &[f64],
    h: f64,
) {
    for i in 0..y0.len() {
        let dy = y1[i] - y0[i];
        let (a, b) = (h * f0[i], h * f1[i]);
        d[0][i] = a;
        d[1][i] = 3.0 * dy - 2.0 * a - b;
        d[2][i] = -2.0 * dy + a + b;
    }
}

/// Whether the step's cubic interpolant stays in [0, 1] in every cell for all
/// theta in [0, 1]: its Bernstein control points do (the curve lies in their
/// convex hull). Conservative: a step that fails is evaluated cell by cell.
fn stays_in_bounds(y0: &[f64], d: &[Vec<f64>; 3]) -> bool {
    let mut inside = true;
    for i in 0..y0.len() {
        let b1 = y0[i] + d[0][i] / 3.0;
        let b2 = y0[i] + (2.0 * d[0][i] + d[1][i]) / 3.0;
        let b3 = y0[i] + d[0][i] + d[1][i] + d[2][i];
        inside &= (0.0..=1.0).contains(&b1)
            & (0.0..=1.0).contains(&b2)
            & (-1e-12..=1.0 + 1e-12).contains(&b3);
    }
    inside
}

/// Evaluate the interpolant into `out`; returns whether it stayed in [0, 1].
#[inline]
fn hermite_eval(out: &mut [f64], y0: &[f64], d: &[Vec<f64>; 3], theta: f64) -> bool {
    let mut outside = false;
    for i in 0..out.len() {
        let v = y0[i] + theta * (d[0][i] + theta * (d[1][i] + theta * d[2][i]));
        out[i] = v;
        // two comparisons, as always: `!(0.0..=1.0).contains(&v)` would also count a NaN as
        // outside, a change of meaning (accepted steps are finite, so it would change nothing seen)
        #[allow(clippy::manual_range_contains)]
        {
            outside |= (v < 0.0) | (v > 1.0);
        }
    }
    !outside
}

fn initial_step<M: NewtonMatrix>(w: &Work<M>, tol: &Tolerances, t_end: f64) -> f64 {
    let scale: Vec<f64> = w.y.iter().map(|v| tol.atol + tol.rtol * v.abs()).collect();
    let d0 = wrms(&w.y, &scale);
    let d1 = wrms(&w.k[0], &scale);
    let h = if d0 > 1e-5 && d1 > 1e-5 {
        0.01 * d0 / d1
    } else {
        1e-6
    };
    h.clamp(1e-8, t_end.max(1e-8))
}

/// Integrate the model from its initial condition and hand the profile at
/// each output time to `sink(index, c)`. The profile passed is in [0, 1].
pub fn integrate(
    p: &Params,
    n_cells: usize,
    t_out: &[f64],
    tol: Tolerances,
    sink: impl FnMut(usize, &[f64]),
) -> Result<Stats, SolveError> {
    integrate_stoppable(p, n_cells, t_out, tol, sink, limits::never())
}

/// `integrate` that returns `SolveError::Interrupted` soon after `stop` is set
/// (it is polled before every step attempt).
pub fn integrate_stoppable(
    p: &Params,
    n_cells: usize,
    t_out: &[f64],
    tol: Tolerances,
    sink: impl FnMut(usize, &[f64]),
    stop: &AtomicBool,
) -> Result<Stats, SolveError> {
    // sizes first: nothing of n_cells is allocated before they pass
    p.validate()?;
    validate_run(n_cells, t_out, &tol)?;
    let mut out = CallbackOutput {
        buf: limits::zeroed(n_cells, "a profile")?,
        sink,
    };
    integrate_with_stop(
        p,
        n_cells,
        t_out,
        tol,
        Tridiagonal::new(n_cells),
        &mut out,
        stop,
    )
}

/// `integrate` with a chosen Newton matrix (see `pressure_coupled`).
pub fn integrate_with<M: NewtonMatrix>(
    p: &Params,
    n_cells: usize,
    t_out: &[f64],
    tol: Tolerances,
    matrix: M,
    out: &mut impl Output,
) -> Result<Stats, SolveError> {
    integrate_with_stop(p, n_cells, t_out, tol, matrix, out, limits::never())
}

/// `integrate_with`, polling `stop` before every step attempt.
pub fn integrate_with_stop<M: NewtonMatrix>(
    p: &Params,
    n_cells: usize,
    t_out: &[f64],
    tol: Tolerances,
    matrix: M,
    out: &mut impl Output,
    stop: &AtomicBool,
) -> Result<Stats, SolveError> {
    integrate_scheme(p, n_cells, t_out, tol, Scheme::default(), matrix, out, stop)
}

/// The layer map (n_t x n_layers, row-major) of one run with a chosen scheme,
/// without the field: what the scheme comparisons (`examples/`) time.
pub fn layer_map_with_scheme(
    p: &Params,
    n_cells: usize,
    t_out: &[f64],
    tol: Tolerances,
    scheme: Scheme,
    n_layers: usize,
) -> Result<(Vec<f64>, Stats), SolveError> {
    layer_map_run(
        p,
        n_cells,
        t_out,
        tol,
        scheme,
        n_layers,
        None,
        limits::never(),
    )
}

/// The one layer-map run: the layer map and stats of a run with `scheme`,
/// differentiating it along `sens`'s tangents when given (`sensitivity.rs`).
#[allow(clippy::too_many_arguments)]
pub fn layer_map_run(
    p: &Params,
    n_cells: usize,
    t_out: &[f64],
    tol: Tolerances,
    scheme: Scheme,
    n_layers: usize,
    sens: Option<&mut Sensitivities>,
    stop: &AtomicBool,
) -> Result<(Vec<f64>, Stats), SolveError> {
    let mut out = LayerOutput::for_run(n_cells, t_out.len(), n_layers)?;
    let matrix = Tridiagonal::new(n_cells);
    let stats = integrate_core(p, n_cells, t_out, tol, scheme, matrix, &mut out, sens, stop)?;
    Ok((out.layers, stats))
}

/// `integrate_with_stop` with a chosen time-stepping scheme.
#[allow(clippy::too_many_arguments)]
pub fn integrate_scheme<M: NewtonMatrix>(
    p: &Params,
    n_cells: usize,
    t_out: &[f64],
    tol: Tolerances,
    scheme: Scheme,
    matrix: M,
    out: &mut impl Output,
    stop: &AtomicBool,
) -> Result<Stats, SolveError> {
    integrate_core(p, n_cells, t_out, tol, scheme, matrix, out, None, stop)
}

/// The one time loop: `integrate_scheme`, differentiating every accepted step
/// along the tangents of `sens` when it is given (`sensitivity.rs`).
#[allow(clippy::too_many_arguments)]
pub fn integrate_core<M: NewtonMatrix>(
    p: &Params,
    n_cells: usize,
    t_out: &[f64],
    tol: Tolerances,
    scheme: Scheme,
    matrix: M,
    out: &mut impl Output,
    mut sens: Option<&mut Sensitivities>,
    stop: &AtomicBool,
) -> Result<Stats, SolveError> {
    p.validate()?;
    validate_run(n_cells, t_out, &tol)?;
    let tab = scheme.tableau();
    let k_last = tab.stages() - 1;
    // the step-size exponent of an error estimate of order q + 1
    let expo = -1.0 / (tab.embedded_order as f64 + 1.0);
    let mut op = Operator::new(*p, n_cells);
    let mut w = Work::new(n_cells, matrix, tab.stages());
    let mut stats = Stats::default();
    w.y = initial_condition(p, &op.grid);
    let mut next = 0;
    while next < t_out.len() && t_out[next] == 0.0 {
        out.profile(next).copy_from_slice(&w.y);
        out.done(next);
        next += 1;
    }
    let t_end = *t_out.last().unwrap();
    let mut t = 0.0;
    op.rhs(t, &w.y, &mut w.k[0]);
    if let Some(sens) = sens.as_deref_mut() {
        sens.start(&op, &w.y);
    }
    let mut h = initial_step(&w, &tol, t_end);
    let mut fresh_jac = true;
    while next < t_out.len() {
        limits::check_stop(stop)?;
        if stats.steps + stats.rejected > MAX_STEPS {
            return Err(SolveError::NewtonFailure {
                t,
                reason: format!("more than {MAX_STEPS} steps"),
            });
        }
        let last = t + h >= t_end * (1.0 - 1e-12);
        if last {
            h = t_end - t;
        }
        match attempt_step(&mut op, &mut w, tab, t, h, &tol, fresh_jac, &mut stats) {
            Attempt::NewtonFailed(reason) => {
                stats.newton_failures += 1;
                stats.rejected += 1;
                h *= 0.25;
                fresh_jac = true;
                op.rhs(t, &w.y, &mut w.fy);
                if h < MIN_STEP {
                    return Err(SolveError::NewtonFailure {
                        t,
                        reason: format!("{reason} even at step size {h:.3e} s"),
                    });
                }
            }
            Attempt::ErrorTooLarge(e) => {
                stats.rejected += 1;
                h *= (0.9 * e.powf(expo)).clamp(0.1, 0.5);
                fresh_jac = false;
                if h < MIN_STEP {
                    return Err(SolveError::NewtonFailure {
                        t,
                        reason: format!("error test failed even at step size {h:.3e} s"),
                    });
                }
            }
            Attempt::Accepted(e) => {
                let t_new = if last { t_end } else { t + h };
                if let Some(sens) = sens.as_deref_mut() {
                    sens.step(&mut op, tab, t, h, t_new, &w.y, &w.k, t_out, next)?;
                }
                // the unclipped state, for clipped_derivative (w.delta is the Newton
                // iteration's scratch, free once the step is accepted)
                w.delta.copy_from_slice(&w.y_new);
                let clip = enforce_bounds(&mut w.y_new);
                if clip > 0.0 {
                    stats.clipped += 1;
                    stats.max_clip = stats.max_clip.max(clip);
                    clipped_derivative(&mut w.k[k_last], &w.y_new, &w.delta, h * tab.gamma);
                }
                hermite_coefficients(&mut w.herm, &w.y, &w.k[0], &w.y_new, &w.k[k_last], h);
                // Layer outputs: the interpolant is linear in its coefficients, so its layer
                // means are the interpolant of the coefficients' layer means, made once per
                // step. Only when no cell can leave [0, 1] within the step (nothing to clip).
                let reduced = match out.layer_map() {
                    Some(map)
                        if next < t_out.len()
                            && t_out[next] <= t_new
                            && stays_in_bounds(&w.y, &w.herm) =>
                    {
                        let n = map.n_layers();
                        w.layer_coef.resize(4 * n, 0.0);
                        let (c0, rest) = w.layer_coef.split_at_mut(n);
                        let (c1, rest) = rest.split_at_mut(n);
                        let (c2, c3) = rest.split_at_mut(n);
                        map.apply(&w.y, c0);
                        map.apply(&w.herm[0], c1);
                        map.apply(&w.herm[1], c2);
                        map.apply(&w.herm[2], c3);
                        true
                    }
                    _ => false,
                };
                while reduced && next < t_out.len() && t_out[next] <= t_new {
                    let theta = ((t_out[next] - t) / h).clamp(0.0, 1.0);
                    let row = out.layer_row(next);
                    let n = row.len();
                    let c = &w.layer_coef;
                    for (l, v) in row.iter_mut().enumerate() {
                        let x = c[l]
                            + theta * (c[n + l] + theta * (c[2 * n + l] + theta * c[3 * n + l]));
                        *v = x.clamp(0.0, 1.0); // rounding only: the cells stay in [0, 1]
                    }
                    next += 1;
                }
                while next < t_out.len() && t_out[next] <= t_new {
                    let theta = ((t_out[next] - t) / h).clamp(0.0, 1.0);
                    let buf = out.profile(next);
                    if !hermite_eval(buf, &w.y, &w.herm, theta) {
                        let clip = enforce_bounds(buf);
                        stats.clipped += 1;
                        stats.max_clip = stats.max_clip.max(clip);
                    }
                    out.done(next);
                    next += 1;
                }
                w.y_prev.copy_from_slice(&w.y);
                w.h_prev = Some(h);
                std::mem::swap(&mut w.y, &mut w.y_new);
                w.k.swap(0, k_last);
                t = t_new;
                stats.steps += 1;
                h *= (0.9 * e.max(1e-10).powf(expo)).clamp(0.2, 4.0);
                fresh_jac = true;
            }
        }
    }
    stats.rhs_evals = op.n_rhs;
    Ok(stats)
}

/// Integrate and return the full profiles, (n_t * n_cells) row-major.
pub fn simulate(
    p: &Params,
    n_cells: usize,
    t_out: &[f64],
    tol: Tolerances,
) -> Result<(Vec<f64>, Stats), SolveError> {
    simulate_stoppable(p, n_cells, t_out, tol, limits::never())
}

/// `simulate` that returns `SolveError::Interrupted` soon after `stop` is set.
pub fn simulate_stoppable(
    p: &Params,
    n_cells: usize,
    t_out: &[f64],
    tol: Tolerances,
    stop: &AtomicBool,
) -> Result<(Vec<f64>, Stats), SolveError> {
    check_simulate(p, n_cells, t_out, &tol)?;
    simulate_with_stop(p, n_cells, t_out, tol, Tridiagonal::new(n_cells), stop)
}

/// Everything a full-output run is given, sizes first, before any allocation:
/// returns the length of the output (n_t x n_cells values, at most
/// `limits::MAX_BYTES`).
pub fn check_simulate(
    p: &Params,
    n_cells: usize,
    t_out: &[f64],
    tol: &Tolerances,
) -> Result<usize, SolveError> {
    let len = limits::check_buffer(
        "the output c",
        &[("len(t)", t_out.len()), ("n_cells", n_cells)],
    )?;
    p.validate()?;
    validate_run(n_cells, t_out, tol)?;
    Ok(len)
}

/// `simulate` with a chosen Newton matrix.
pub fn simulate_with<M: NewtonMatrix>(
    p: &Params,
    n_cells: usize,
    t_out: &[f64],
    tol: Tolerances,
    matrix: M,
) -> Result<(Vec<f64>, Stats), SolveError> {
    simulate_with_stop(p, n_cells, t_out, tol, matrix, limits::never())
}

/// `simulate_with`, polling `stop` before every step attempt.
pub fn simulate_with_stop<M: NewtonMatrix>(
    p: &Params,
    n_cells: usize,
    t_out: &[f64],
    tol: Tolerances,
    matrix: M,
    stop: &AtomicBool,
) -> Result<(Vec<f64>, Stats), SolveError> {
    let len = check_simulate(p, n_cells, t_out, &tol)?;
    let mut out = FullOutput {
        n: n_cells,
        c: limits::reserved(len, "the output c")?,
    };
    let stats = integrate_with_stop(p, n_cells, t_out, tol, matrix, &mut out, stop)?;
    debug_assert_eq!(out.c.len(), len, "every output time is written");
    Ok((out.c, stats))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn times(end: f64, dt: f64) -> Vec<f64> {
        (0..=((end / dt) as usize)).map(|i| i as f64 * dt).collect()
    }

    #[test]
    fn conserves_mass_and_bounds_for_glass_pp() {
        let p = Params::default();
        let n = 180;
        let t = times(3600.0, 2.0);
        let (c, stats) = simulate(&p, n, &t, Tolerances::default()).unwrap();
        let m0: f64 = c[..n].iter().sum();
        for k in 0..t.len() {
            let row = &c[k * n..(k + 1) * n];
            let m: f64 = row.iter().sum();
            assert!(
                ((m - m0) / m0).abs() < 1e-12,
                "mass drift {} at t={}",
                (m - m0) / m0,
                t[k]
            );
            assert!(row.iter().all(|&v| (0.0..=1.0).contains(&v)));
        }
        assert!(stats.steps < 400, "{stats:?}");
        // heavy at the bottom in the end
        let last = &c[(t.len() - 1) * n..];
        assert!(
            last[0] > 0.8 && last[n - 1] < 0.2,
            "{} {}",
            last[0],
            last[n - 1]
        );
    }

    #[test]
    fn equal_densities_mix_to_c0() {
        let p = Params {
            rho_h: 2450.0,
            rho_l: 2450.0,
            c0: 0.3,
            ..Params::default()
        };
        let (c, _) = simulate(&p, 60, &[0.0, 2.0e5], Tolerances::default()).unwrap();
        for v in &c[60..] {
            assert!((v - 0.3).abs() < 1e-3, "{v}");
        }
    }

    #[test]
    fn rejects_bad_input() {
        let p = Params::default();
        assert!(simulate(&p, 10, &[0.0, 1.0], Tolerances::default()).is_err());
        assert!(simulate(&p, 30, &[0.0, 0.0], Tolerances::default()).is_err());
        assert!(simulate(&p, 30, &[-1.0, 1.0], Tolerances::default()).is_err());
        assert!(simulate(
            &p,
            30,
            &[0.0, 1.0],
            Tolerances {
                rtol: 0.0,
                atol: 1e-6
            }
        )
        .is_err());
    }

    /// A Newton matrix that can never be factorised: the stepper must retry
    /// with smaller steps, then report where and why it stopped.
    struct Singular;
    impl NewtonMatrix for Singular {
        fn update(&mut self, _op: &Operator, _c: &[f64]) {}
        fn factor(&mut self, _s: f64) -> bool {
            false
        }
        fn solve(&mut self, _x: &mut [f64]) {}
    }

    #[test]
    fn newton_failure_retries_then_reports_time_and_reason() {
        let p = Params::default();
        let mut out = FullOutput {
            n: 30,
            c: vec![0.0; 60],
        };
        let err = integrate_with(
            &p,
            30,
            &[0.0, 100.0],
            Tolerances::default(),
            Singular,
            &mut out,
        )
        .unwrap_err();
        match &err {
            SolveError::NewtonFailure { t, reason } => {
                assert_eq!(*t, 0.0);
                assert!(
                    reason.contains("singular") && reason.contains("step size"),
                    "{reason}"
                );
            }
            other => panic!("unexpected {other:?}"),
        }
        assert!(!err.is_input_error());
        assert!(err.to_string().contains("t = 0 s"), "{err}");
    }

    #[test]
    fn sizes_are_refused_before_allocation() {
        let p = Params::default();
        let t = times(3600.0, 2.0);
        // the 28.8 GB: an error naming the sizes and the bytes, not an abort
        let e = simulate(&p, 2_000_000, &t, Tolerances::default()).unwrap_err();
        let m = e.to_string();
        assert!(e.is_input_error(), "{e:?}");
        assert!(
            m.contains("28816000000 bytes")
                && m.contains("n_cells = 2000000")
                && m.contains("len(t) = 1801"),
            "{m}"
        );
        // sizes whose product overflows, and a grid no buffer is made for
        assert!(simulate(&p, usize::MAX / 2, &t, Tolerances::default())
            .unwrap_err()
            .to_string()
            .contains("more than"));
        let e = integrate(
            &p,
            1usize << 40,
            &[0.0, 1.0],
            Tolerances::default(),
            |_, _| {},
        )
        .unwrap_err();
        assert!(e.to_string().contains("n_cells = 1099511627776"), "{e}");
        // too many output times, even where the bytes would fit
        let many: Vec<f64> = (0..=limits::MAX_OUTPUT_TIMES).map(|i| i as f64).collect();
        let e = integrate(&p, 15, &many, Tolerances::default(), |_, _| {}).unwrap_err();
        assert!(
            e.to_string().starts_with("t has 1000001 output times"),
            "{e}"
        );
    }

    #[test]
    fn a_set_stop_flag_interrupts_the_run() {
        let p = Params::default();
        let stop = AtomicBool::new(true);
        let e =
            simulate_stoppable(&p, 60, &[0.0, 3600.0], Tolerances::default(), &stop).unwrap_err();
        assert_eq!(e, SolveError::Interrupted);
        assert!(!e.is_input_error());
        // only t = 0 needs no step: it is not interrupted
        assert!(simulate_stoppable(&p, 60, &[0.0], Tolerances::default(), &stop).is_ok());
    }

    /// The classical order conditions of a Runge-Kutta tableau (b, A, c) up to
    /// order `p` (trees of order <= 5), as (name, residual).
    fn order_residuals(b: &[f64], t: &Tableau, p: u32) -> Vec<(String, f64)> {
        let n = b.len();
        let av = |v: &[f64]| -> Vec<f64> {
            (0..n)
                .map(|i| t.a[i].iter().zip(v).map(|(a, x)| a * x).sum())
                .collect()
        };
        let mul =
            |x: &[f64], y: &[f64]| -> Vec<f64> { x.iter().zip(y).map(|(a, b)| a * b).collect() };
        let bdot = |v: &[f64]| -> f64 { b.iter().zip(v).map(|(a, x)| a * x).sum() };
        let c = t.c.to_vec();
        let one = vec![1.0; n];
        let c2 = mul(&c, &c);
        let c3 = mul(&c2, &c);
        let ac = av(&c);
        let ac2 = av(&c2);
        let aac = av(&ac);
        let mut out = vec![("1".to_string(), bdot(&one) - 1.0)];
        if p >= 2 {
            out.push(("c".into(), bdot(&c) - 0.5));
        }
        if p >= 3 {
            out.push(("c2".into(), bdot(&c2) - 1.0 / 3.0));
            out.push(("Ac".into(), bdot(&ac) - 1.0 / 6.0));
        }
        if p >= 4 {
            out.push(("c3".into(), bdot(&c3) - 0.25));
            out.push(("cAc".into(), bdot(&mul(&c, &ac)) - 1.0 / 8.0));
            out.push(("Ac2".into(), bdot(&ac2) - 1.0 / 12.0));
            out.push(("AAc".into(), bdot(&aac) - 1.0 / 24.0));
        }
        if p >= 5 {
            out.push(("c4".into(), bdot(&mul(&c3, &c)) - 0.2));
            out.push(("c2Ac".into(), bdot(&mul(&c2, &ac)) - 0.1));
            out.push(("Ac3".into(), bdot(&av(&c3)) - 0.05));
            out.push(("AAAc".into(), bdot(&av(&aac)) - 1.0 / 120.0));
            out.push(("cAAc".into(), bdot(&mul(&c, &aac)) - 1.0 / 30.0));
            out.push(("(Ac)2".into(), bdot(&mul(&ac, &ac)) - 0.05));
            out.push(("cAc2".into(), bdot(&mul(&c, &ac2)) - 1.0 / 15.0));
            out.push(("AcAc".into(), bdot(&av(&mul(&c, &ac))) - 1.0 / 40.0));
            out.push(("AAc2".into(), bdot(&av(&ac2)) - 1.0 / 60.0));
        }
        out
    }

    #[test]
    fn tableaus_meet_their_order_conditions() {
        // a typo in one of the long rationals breaks one of these
        for (t, order) in [(&ESDIRK3, 3), (&ESDIRK4, 4), (&ESDIRK5, 5)] {
            let n = t.stages();
            assert_eq!(
                (t.a.len(), t.b_hat.len(), t.c.len()),
                (n, n, n),
                "{}",
                t.name
            );
            for i in 0..n {
                assert_eq!(t.a[i].len(), i + 1, "{} row {i}", t.name);
                let sum: f64 = t.a[i].iter().sum();
                assert!((sum - t.c[i]).abs() < 1e-12, "{} row sum {i}", t.name);
                if i > 0 {
                    assert_eq!(t.a[i][i], t.gamma, "{} diagonal {i}", t.name);
                }
            }
            assert_eq!(t.b, t.a[n - 1], "{}: stiffly accurate", t.name);
            assert_eq!(t.c[n - 1], 1.0);
            for (name, r) in order_residuals(t.b, t, order) {
                assert!(r.abs() < 1e-11, "{} order condition {name}: {r:e}", t.name);
            }
            let embedded = order_residuals(t.b_hat, t, t.embedded_order);
            for (name, r) in embedded {
                assert!(
                    r.abs() < 1e-11,
                    "{} embedded condition {name}: {r:e}",
                    t.name
                );
            }
            // the embedding is of exactly that order: some condition of the next fails
            let next = order_residuals(t.b_hat, t, t.embedded_order + 1);
            assert!(next.iter().any(|(_, r)| r.abs() > 1e-6), "{}", t.name);
        }
    }

    #[test]
    fn default_tolerances_hold_at_a_stiff_steady_state() {
        // the default_survey example's hardest case: few heavy grains, steady
        // long before 3600 s, steps of hundreds of seconds; a clip re-evaluating
        // the state's derivative once bent its outputs by 2.6e-3
        let p = Params {
            rho_h: 5528.923646192358,
            rho_l: 946.0,
            c0: 0.2000662011898057,
            k: 0.5509447371591336,
            delta_over_h: 0.16216022093156965,
            ..Params::default()
        };
        let t = times(3600.0, 2.0);
        let fine = Tolerances {
            rtol: 1e-9,
            atol: 1e-11,
        };
        let (reference, _) =
            layer_map_with_scheme(&p, 1440, &t, fine, Scheme::Esdirk3, 15).unwrap();
        let (got, stats) =
            layer_map_with_scheme(&p, 180, &t, Tolerances::default(), Scheme::Esdirk3, 15).unwrap();
        let err = got
            .iter()
            .zip(&reference)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(stats.clipped > 0, "the case must clip to test the clip");
        assert!(err < 1e-3, "layer error {err:e}");
    }

    #[test]
    fn bounds_enforcement_conserves_mass() {
        let mut c = vec![-1e-9, 0.2, 0.5, 1.0 + 3e-9, 0.7];
        let m0: f64 = c.iter().sum();
        assert!((enforce_bounds(&mut c) - 3e-9).abs() < 1e-15);
        let m1: f64 = c.iter().sum();
        assert!((m1 - m0).abs() < 1e-15);
        assert!(c.iter().all(|v| (0.0..=1.0).contains(v)));
    }
}
