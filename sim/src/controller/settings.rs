//! Grbl's settings (`$0`…`$132`): their kinds and defaults, reading the value
//! in force, writing one with the effect Grbl gives it, and restoring them.
//! Separate from the `$` commands in `system.rs` that print and parse them,
//! because the rest of the controller reads settings everywhere.

use super::{Controller, Flavor};

/// How a setting is stored and printed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Kind {
    /// Whole number, written truncated.
    Int,
    /// 0 or 1 (any non-zero whole part counts as 1).
    Bool,
    /// Float printed without decimals (`$30`, `$31`).
    Rpm,
    /// Float printed with 3 decimals.
    Float,
}

impl Controller {
    /// Every setting with its kind and value in force (written or default),
    /// `$0`–`$32` then per axis `$100+i`, `$110+i`, `$120+i`, `$130+i`.
    pub(super) fn settings(&self) -> Vec<(u32, Kind, f64)> {
        use Kind::*;
        let d = &self.proto.defaults;
        let mut s = vec![
            (0, Int, 10.0),
            (1, Int, 25.0),
            (2, Int, 0.0),
            (3, Int, 0.0),
            (4, Bool, 0.0),
            (5, Bool, 0.0),
            (6, Bool, 0.0),
            // Grbl 1.1h's default: MPos only, no `Bf:` (grblHAL reports the
            // buffers by default).
            (10, Int, if self.cfg.flavor == Flavor::Grblhal { 3.0 } else { 1.0 }),
            (11, Float, d.junction_deviation),
            (12, Float, 0.002),
            (13, Bool, 0.0),
            // Grbl's defaults: soft limits off, and they need homing ($22).
            (20, Bool, 0.0),
            (21, Bool, 0.0),
            (22, Bool, 0.0),
            (23, Int, 0.0),
            (24, Float, 25.0),
            (25, Float, 500.0),
            (26, Int, 250.0),
            (27, Float, 1.0),
            (30, Rpm, d.laser_max_s),
            (31, Rpm, 0.0),
            (32, Bool, 1.0),
        ];
        let n = d.axes.len() as u32;
        s.extend((0..n).map(|i| (100 + i, Float, super::STEPS_PER_MM)));
        s.extend(d.axes.iter().zip(0..).map(|(a, i)| (110 + i, Float, a.max_velocity * 60.0)));
        s.extend(d.axes.iter().zip(0..).map(|(a, i)| (120 + i, Float, a.max_acceleration)));
        s.extend(d.axes.iter().zip(0..).map(|(a, i)| (130 + i, Float, a.max - a.min)));
        for (k, _, v) in &mut s {
            if let Some(w) = self.written_settings.get(k) {
                *v = *w;
            }
        }
        s
    }

    /// Value of setting `n` in force (0 for an unknown one).
    pub(super) fn setting(&self, n: u32) -> f64 {
        self.written_settings
            .get(&n)
            .copied()
            .unwrap_or_else(|| self.settings().into_iter().find(|(k, _, _)| *k == n).map_or(0.0, |(_, _, v)| v))
    }

    /// The `$10` status report mask in force. Grbl 1.1 uses bit 0 (MPos, else
    /// WPos) and bit 1 (`Bf:`); the other bits are grblHAL's and do nothing here.
    pub(super) fn status_mask(&self) -> u32 {
        self.setting(10) as u32 & 3
    }

    /// Soft limits (`$20`) in force.
    pub(super) fn soft_limits(&self) -> bool {
        self.setting(20) != 0.0
    }

    /// A machine position outside Grbl's machine space: every axis from
    /// minus its max travel (`$130`..) up to 0, whichever way it homes (`$23`
    /// only moves where homing ends; Grbl built without
    /// HOMING_FORCE_SET_ORIGIN, as this one is: no `Z` in `[OPT:]`).
    pub(super) fn beyond_travel(&self, target: &[f64]) -> bool {
        const EPS: f64 = 1e-6;
        target.iter().zip(0..).any(|(p, i)| *p > EPS || *p < -self.setting(130 + i) - EPS)
    }

    /// Writes setting `n` (`$n=value`), with the effect Grbl gives it.
    pub(super) fn write_setting(&mut self, n: u32, v: f64) -> Result<(), u16> {
        let Some(kind) = self.settings().iter().find(|(k, _, _)| *k == n).map(|s| s.1) else {
            return Err(3);
        };
        if v < 0.0 {
            return Err(4);
        }
        let v = match kind {
            Kind::Int => v.trunc(),
            Kind::Bool => f64::from(u8::from(v.trunc() != 0.0)),
            Kind::Rpm | Kind::Float => v,
        };
        if n == 0 && v < 3.0 {
            return Err(6);
        }
        if n == 20 && v != 0.0 && self.setting(22) == 0.0 {
            return Err(10);
        }
        let axis = |base: u32| (n >= base && n < base + 10).then(|| (n - base) as usize);
        // A zero rate or acceleration would stall the machine model: it is
        // stored and printed, but the axis keeps its last usable value.
        if let Some(i) = axis(110).filter(|_| v > 0.0) {
            self.cfg.axes[i].max_velocity = v / 60.0;
        } else if let Some(i) = axis(120).filter(|_| v > 0.0) {
            self.cfg.axes[i].max_acceleration = v;
        } else if let Some(i) = axis(130) {
            let a = &mut self.cfg.axes[i];
            a.max = a.min + v;
        } else if n == 30 && v > 0.0 {
            self.cfg.laser_max_s = v;
        }
        self.written_settings.insert(n, v);
        if n == 32 {
            // The laser at rest is a laser-mode state (see `rest_power`).
            self.rest_s = 0.0;
        }
        if n == 22 && v == 0.0 {
            // Soft limits need homing: switching homing off switches them off.
            self.written_settings.insert(20, 0.0);
        }
        Ok(())
    }

    /// `$RST=$`: every setting back to the configured default.
    pub(super) fn restore_settings(&mut self) {
        self.written_settings.clear();
        let d = &self.proto.defaults;
        for (a, da) in self.cfg.axes.iter_mut().zip(&d.axes) {
            a.max_velocity = da.max_velocity;
            a.max_acceleration = da.max_acceleration;
            a.min = da.min;
            a.max = da.max;
        }
        self.cfg.laser_max_s = d.laser_max_s;
    }
}

/// A setting value as Grbl reads it: optional sign, digits, one point; no
/// exponent, no `inf`/`nan`.
pub(super) fn parse_value(s: &str) -> Option<f64> {
    let body = s.strip_prefix(['-', '+']).unwrap_or(s);
    let ok = body.bytes().any(|b| b.is_ascii_digit())
        && body.bytes().all(|b| b.is_ascii_digit() || b == b'.')
        && body.bytes().filter(|b| *b == b'.').count() <= 1;
    ok.then(|| s.parse::<f64>().ok()).flatten().filter(|v| v.is_finite())
}
