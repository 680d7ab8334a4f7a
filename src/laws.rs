//! Open-world corrections of the baseline's constitutive laws (a named option,
//! off by default: every table zero is docs/model.md exactly).
//!
//! Each correction is a log-factor tabulated at `N_KNOTS` evenly spaced knots
//! of a variable scaled to [0, 1], linearly interpolated and clamped at the
//! ends:
//!
//! | table          | multiplies                         | variable        |
//! |----------------|------------------------------------|-----------------|
//! | `law_flux_c`   | the segregation speed w            | c (face mean)   |
//! | `law_diff_z`   | the diffusivity D                  | z / H           |
//! | `law_diff_t`   | the diffusivity D                  | t / `law_time`  |
//! | `law_shear_z`  | the shear rate (so w, D and I)     | z / H           |
//! | `law_rate_t`   | both w and D                       | t / `law_time`  |
//!
//! The tables are set knot by knot through the parameter names
//! `law_flux_c_0` .. `law_flux_c_16` (and so on), so that the Python side keeps
//! its flat dict of floats; the fitting layer fills them from a smooth,
//! low-dimensional basis, and virtual campaigns from forms of their own.

use crate::error::SolveError;

/// Knots of every table.
pub const N_KNOTS: usize = 17;
/// Largest |log-factor| accepted (a factor of e^6 ~ 400 either way).
pub const MAX_LOG_FACTOR: f64 = 6.0;
/// The tables by parameter-name prefix, in a fixed order.
pub const TABLES: [&str; 5] = [
    "law_flux_c",
    "law_diff_z",
    "law_diff_t",
    "law_shear_z",
    "law_rate_t",
];

/// One log-factor table on [0, 1].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Table(pub [f64; N_KNOTS]);

impl Table {
    /// True when every knot is zero (the factor is 1 everywhere).
    pub fn is_zero(&self) -> bool {
        self.0.iter().all(|v| *v == 0.0)
    }

    /// The log-factor at x (clamped to [0, 1]), linearly interpolated.
    #[inline]
    pub fn log_factor(&self, x: f64) -> f64 {
        let s = x.clamp(0.0, 1.0) * (N_KNOTS - 1) as f64;
        let i = (s.floor() as usize).min(N_KNOTS - 2);
        let w = s - i as f64;
        self.0[i] * (1.0 - w) + self.0[i + 1] * w
    }

    /// d log_factor / dx (0 where x is clamped; the right-hand slope at a knot).
    #[inline]
    pub fn log_factor_slope(&self, x: f64) -> f64 {
        if !(0.0..=1.0).contains(&x) {
            return 0.0;
        }
        let s = x * (N_KNOTS - 1) as f64;
        let i = (s.floor() as usize).min(N_KNOTS - 2);
        (self.0[i + 1] - self.0[i]) * (N_KNOTS - 1) as f64
    }

    /// The factor exp(log_factor(x)).
    #[inline]
    pub fn factor(&self, x: f64) -> f64 {
        self.log_factor(x).exp()
    }
}

/// Every correction, plus the time scale of the time tables.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Laws {
    pub flux_c: Table,
    pub diff_z: Table,
    pub diff_t: Table,
    pub shear_z: Table,
    pub rate_t: Table,
    /// The time that maps to 1 on the time tables, s.
    pub time_scale: f64,
}

impl Default for Laws {
    fn default() -> Self {
        Laws {
            flux_c: Table::default(),
            diff_z: Table::default(),
            diff_t: Table::default(),
            shear_z: Table::default(),
            rate_t: Table::default(),
            time_scale: 3600.0,
        }
    }
}

fn split(key: &str) -> Option<(usize, usize)> {
    let (prefix, index) = key.rsplit_once('_')?;
    let table = TABLES.iter().position(|t| *t == prefix)?;
    let knot: usize = index.parse().ok()?;
    (knot < N_KNOTS && index == knot.to_string()).then_some((table, knot))
}

impl Laws {
    fn table(&self, i: usize) -> &Table {
        [
            &self.flux_c,
            &self.diff_z,
            &self.diff_t,
            &self.shear_z,
            &self.rate_t,
        ][i]
    }

    fn table_mut(&mut self, i: usize) -> &mut Table {
        match i {
            0 => &mut self.flux_c,
            1 => &mut self.diff_z,
            2 => &mut self.diff_t,
            3 => &mut self.shear_z,
            _ => &mut self.rate_t,
        }
    }

    /// Every knot's parameter name, table by table.
    pub fn keys() -> Vec<String> {
        TABLES
            .iter()
            .flat_map(|t| (0..N_KNOTS).map(move |k| format!("{t}_{k}")))
            .collect()
    }

    /// Set a knot by its parameter name; None if the name is not a knot's.
    pub fn set(&mut self, key: &str, value: f64) -> Option<()> {
        let (t, k) = split(key)?;
        self.table_mut(t).0[k] = value;
        Some(())
    }

    /// Read a knot by its parameter name.
    pub fn get(&self, key: &str) -> Option<f64> {
        split(key).map(|(t, k)| self.table(t).0[k])
    }

    /// True when any table is non-zero.
    pub fn active(&self) -> bool {
        (0..TABLES.len()).any(|i| !self.table(i).is_zero())
    }

    /// True when a time table is non-zero (the faces change with time).
    pub fn time_dependent(&self) -> bool {
        !(self.diff_t.is_zero() && self.rate_t.is_zero())
    }

    /// Every knot finite and within +-`MAX_LOG_FACTOR`, the time scale positive.
    pub fn validate(&self) -> Result<(), SolveError> {
        for (i, name) in TABLES.iter().enumerate() {
            for (k, v) in self.table(i).0.iter().enumerate() {
                if !v.is_finite() || v.abs() > MAX_LOG_FACTOR {
                    return Err(SolveError::InvalidParameter {
                        name: format!("{name}_{k}"),
                        value: *v,
                        range: format!("a log-factor in [-{MAX_LOG_FACTOR}, {MAX_LOG_FACTOR}]"),
                    });
                }
            }
        }
        if !(self.time_scale.is_finite() && self.time_scale > 0.0) {
            return Err(SolveError::InvalidParameter {
                name: "law_time".into(),
                value: self.time_scale,
                range: "> 0 s".into(),
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tables_interpolate_and_clamp() {
        let mut t = Table::default();
        t.0[0] = 1.0;
        t.0[1] = 3.0;
        let h = 1.0 / (N_KNOTS - 1) as f64;
        assert_eq!(t.log_factor(0.0), 1.0);
        assert!((t.log_factor(0.5 * h) - 2.0).abs() < 1e-12);
        assert_eq!(t.log_factor(-1.0), 1.0);
        assert_eq!(t.log_factor(2.0), 0.0);
        assert_eq!(t.log_factor(1.0), 0.0);
    }

    #[test]
    fn knots_are_named_and_checked() {
        let mut laws = Laws::default();
        assert!(!laws.active());
        assert_eq!(Laws::keys().len(), TABLES.len() * N_KNOTS);
        laws.set("law_diff_t_16", 0.5).unwrap();
        assert_eq!(laws.get("law_diff_t_16"), Some(0.5));
        assert!(laws.active() && laws.time_dependent());
        assert!(laws.set("law_diff_t_17", 1.0).is_none());
        assert!(laws.set("law_diff_t_01", 1.0).is_none());
        assert!(laws.set("law_nope_1", 1.0).is_none());
        laws.set("law_flux_c_3", 7.0).unwrap();
        let err = laws.validate().unwrap_err().to_string();
        assert!(err.contains("law_flux_c_3"), "{err}");
    }
}
