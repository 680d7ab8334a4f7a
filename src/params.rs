//! Model parameters: the single source of truth for docs/model.md's constants.
//!
//! Python reads the defaults from here (`_core.defaults()`), so no constant is
//! ever copied by hand into another language.

use crate::error::SolveError;
use crate::laws::Laws;

/// Every physical parameter of the baseline model plus the extension hooks.
/// SI units throughout.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Params {
    /// Heavy solid density, kg/m^3.
    pub rho_h: f64,
    /// Light solid density, kg/m^3.
    pub rho_l: f64,
    /// Overall heavy volume share, (0, 1).
    pub c0: f64,
    /// Friction correction factor, mu* = k mu(I).
    pub k: f64,
    /// Shear-band decay length over bed height, delta / H.
    pub delta_over_h: f64,
    /// Slip speed at the top lid, m/s.
    pub v1: f64,
    /// Diffusion constant in D = b gdot D_p^2.
    pub b: f64,
    /// Particle diameter, m.
    pub d_p: f64,
    /// Bed height, m.
    pub h: f64,
    /// Solids volume fraction.
    pub phi_s: f64,
    /// Gravity, m/s^2.
    pub g: f64,
    /// mu(I) law: minimum friction.
    pub mu_min: f64,
    /// mu(I) law: saturation friction.
    pub mu_2: f64,
    /// mu(I) law: I0.
    pub i0: f64,
    /// Load on the lid, kg.
    pub m_w: f64,
    /// Bottom-plate speed, revolutions per minute.
    pub rpm: f64,
    /// Inner cylinder diameter, m.
    pub d_in: f64,
    /// Outer cylinder diameter, m.
    pub d_out: f64,
    /// Extension `evolving_shear_band`: relative drift of delta over an
    /// experiment, delta(t) = delta (1 + drift (1 - exp(-t / drift_time))).
    /// 0 is the baseline.
    pub delta_drift: f64,
    /// Time scale of the drift, s.
    pub delta_drift_time: f64,
    /// Open-world corrections of the constitutive laws (all zero: docs/model.md).
    pub laws: Laws,
}

impl Default for Params {
    fn default() -> Self {
        Params {
            rho_h: 2450.0,
            rho_l: 946.0,
            c0: 0.5,
            k: 0.70,
            delta_over_h: 0.18,
            v1: 0.0,
            b: 0.041,
            d_p: 6.0e-3,
            h: 0.090,
            phi_s: 0.60,
            g: 9.81,
            mu_min: 20.90_f64.to_radians().tan(),
            mu_2: 32.76_f64.to_radians().tan(),
            i0: 0.279,
            m_w: 1.093,
            rpm: 23.44,
            d_in: 0.090,
            d_out: 0.190,
            delta_drift: 0.0,
            delta_drift_time: 600.0,
            laws: Laws::default(),
        }
    }
}

/// Material densities of docs/model.md, kg/m^3.
pub const MATERIALS: [(&str, f64); 5] = [
    ("steel", 7800.0),
    ("ceramic", 3500.0),
    ("glass", 2450.0),
    ("POM", 1750.0),
    ("PP", 946.0),
];

type Field = (&'static str, fn(&Params) -> f64, fn(&mut Params, f64));

/// Python-facing names (as in docs/model.md) with accessors, in a fixed order.
pub const FIELDS: [Field; 21] = [
    ("rho_h", |p| p.rho_h, |p, v| p.rho_h = v),
    ("rho_l", |p| p.rho_l, |p, v| p.rho_l = v),
    ("c0", |p| p.c0, |p, v| p.c0 = v),
    ("k", |p| p.k, |p, v| p.k = v),
    (
        "delta_over_H",
        |p| p.delta_over_h,
        |p, v| p.delta_over_h = v,
    ),
    ("v1", |p| p.v1, |p, v| p.v1 = v),
    ("b", |p| p.b, |p, v| p.b = v),
    ("D_p", |p| p.d_p, |p, v| p.d_p = v),
    ("H", |p| p.h, |p, v| p.h = v),
    ("phi_s", |p| p.phi_s, |p, v| p.phi_s = v),
    ("g", |p| p.g, |p, v| p.g = v),
    ("mu_min", |p| p.mu_min, |p, v| p.mu_min = v),
    ("mu_2", |p| p.mu_2, |p, v| p.mu_2 = v),
    ("I0", |p| p.i0, |p, v| p.i0 = v),
    ("M_w", |p| p.m_w, |p, v| p.m_w = v),
    ("rpm", |p| p.rpm, |p, v| p.rpm = v),
    ("D_in", |p| p.d_in, |p, v| p.d_in = v),
    ("D_out", |p| p.d_out, |p, v| p.d_out = v),
    ("delta_drift", |p| p.delta_drift, |p, v| p.delta_drift = v),
    (
        "delta_drift_time",
        |p| p.delta_drift_time,
        |p, v| p.delta_drift_time = v,
    ),
    (
        "law_time",
        |p| p.laws.time_scale,
        |p, v| p.laws.time_scale = v,
    ),
];

impl Params {
    /// Set a parameter by its docs/model.md name (or a law knot's, see `laws`).
    pub fn set(&mut self, name: &str, value: f64) -> Result<(), SolveError> {
        match FIELDS.iter().find(|f| f.0 == name) {
            Some(f) => {
                (f.2)(self, value);
                Ok(())
            }
            None => self
                .laws
                .set(name, value)
                .ok_or_else(|| SolveError::UnknownParameter(name.to_string())),
        }
    }

    /// Read a parameter by its docs/model.md name (or a law knot's).
    pub fn get(&self, name: &str) -> Option<f64> {
        FIELDS
            .iter()
            .find(|f| f.0 == name)
            .map(|f| (f.1)(self))
            .or_else(|| self.laws.get(name))
    }

    /// Build from (name, value) pairs on top of the defaults, then validate.
    pub fn from_pairs<'a>(
        pairs: impl IntoIterator<Item = (&'a str, f64)>,
    ) -> Result<Self, SolveError> {
        let mut p = Params::default();
        for (name, value) in pairs {
            p.set(name, value)?;
        }
        p.validate()?;
        Ok(p)
    }

    /// Angular speed of the bottom plate, rad/s.
    pub fn omega(&self) -> f64 {
        self.rpm * 2.0 * std::f64::consts::PI / 60.0
    }

    /// Bottom-wall speed at the outer wall, m/s.
    pub fn v0(&self) -> f64 {
        self.omega() * self.d_out / 2.0
    }

    /// Annulus area, m^2.
    pub fn area(&self) -> f64 {
        std::f64::consts::PI * (self.d_out * self.d_out - self.d_in * self.d_in) / 4.0
    }

    /// Lid pressure M_w g / A, Pa.
    pub fn p_load(&self) -> f64 {
        self.m_w * self.g / self.area()
    }

    /// Shear-band decay length at time t, m.
    pub fn delta_at(&self, t: f64) -> f64 {
        let drift = if self.delta_drift == 0.0 {
            0.0
        } else {
            self.delta_drift * (1.0 - (-t / self.delta_drift_time).exp())
        };
        self.delta_over_h * self.h * (1.0 + drift)
    }

    /// Mixture density, kg/m^3.
    #[inline]
    pub fn rho_m(&self, c: f64) -> f64 {
        self.rho_h * c + self.rho_l * (1.0 - c)
    }

    /// Check every parameter against its physical range, naming the first
    /// offender and the range it must lie in.
    pub fn validate(&self) -> Result<(), SolveError> {
        let checks: [(&str, f64, bool, &str); 20] = [
            ("rho_h", self.rho_h, self.rho_h > 0.0, "> 0 kg/m^3"),
            ("rho_l", self.rho_l, self.rho_l > 0.0, "> 0 kg/m^3"),
            ("c0", self.c0, self.c0 > 0.0 && self.c0 < 1.0, "in (0, 1)"),
            ("k", self.k, self.k > 0.0, "> 0"),
            (
                "delta_over_H",
                self.delta_over_h,
                self.delta_over_h > 0.0,
                "> 0",
            ),
            ("b", self.b, self.b > 0.0, "> 0"),
            // a bed of fewer than two grains is no granular continuum (and
            // the initial interface, smoothed over one diameter, needs room)
            (
                "D_p",
                self.d_p,
                self.d_p > 0.0 && self.d_p <= 0.5 * self.h,
                "in (0, H/2] m",
            ),
            ("H", self.h, self.h > 0.0, "> 0 m"),
            (
                "phi_s",
                self.phi_s,
                self.phi_s > 0.0 && self.phi_s <= 1.0,
                "in (0, 1]",
            ),
            ("g", self.g, self.g > 0.0, "> 0 m/s^2"),
            ("mu_min", self.mu_min, self.mu_min > 0.0, "> 0"),
            ("mu_2", self.mu_2, self.mu_2 >= self.mu_min, ">= mu_min"),
            ("I0", self.i0, self.i0 > 0.0, "> 0"),
            ("M_w", self.m_w, self.m_w > 0.0, "> 0 kg"),
            ("rpm", self.rpm, self.rpm > 0.0, "> 0"),
            ("D_in", self.d_in, self.d_in > 0.0, "> 0 m"),
            ("D_out", self.d_out, self.d_out > self.d_in, "> D_in"),
            // after rpm and the diameters it is computed from, so that a bad rpm
            // or D_out is named as itself, not as v1
            (
                "v1",
                self.v1,
                self.v1 < self.v0(),
                "< v0 (the bottom-wall speed)",
            ),
            (
                "delta_drift",
                self.delta_drift,
                self.delta_drift > -1.0,
                "> -1",
            ),
            (
                "delta_drift_time",
                self.delta_drift_time,
                self.delta_drift_time > 0.0,
                "> 0 s",
            ),
        ];
        self.laws.validate()?;
        for (name, value, ok, range) in checks {
            if !value.is_finite() || !ok {
                return Err(SolveError::InvalidParameter {
                    name: name.to_string(),
                    value,
                    range: range.to_string(),
                });
            }
        }
        if self.rho_h < self.rho_l {
            return Err(SolveError::InvalidParameter {
                name: "rho_h".into(),
                value: self.rho_h,
                range: format!(
                    ">= rho_l = {} kg/m^3 (the heavy species is the denser)",
                    self.rho_l
                ),
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_match_model_md() {
        let p = Params::default();
        assert!((p.v0() - 0.2331900).abs() < 1e-6);
        assert!((p.area() - 2.19911e-2).abs() < 1e-6);
        assert!((p.p_load() - 487.575).abs() < 1e-2);
        assert!((p.mu_min - 0.381863).abs() < 1e-6);
        assert!((p.mu_2 - 0.643468).abs() < 1e-6);
        p.validate().unwrap();
    }

    #[test]
    fn every_field_round_trips() {
        let mut p = Params::default();
        for (i, (name, _, _)) in FIELDS.iter().enumerate() {
            p.set(name, i as f64 + 0.5).unwrap();
            assert_eq!(p.get(name), Some(i as f64 + 0.5));
        }
        assert!(p.set("nope", 1.0).is_err());
    }

    #[test]
    fn validation_names_the_parameter() {
        let err = Params::from_pairs([("c0", 1.5)]).unwrap_err();
        assert!(err.to_string().contains("c0"), "{err}");
        let err = Params::from_pairs([("rho_h", 900.0)]).unwrap_err();
        assert!(err.to_string().contains("rho_h"), "{err}");
        let err = Params::from_pairs([("k", f64::NAN)]).unwrap_err();
        assert!(err.to_string().contains('k'), "{err}");
    }
}
