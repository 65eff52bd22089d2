//! Effects the default compensation model does not know about (`--hidden SPEC`).

use super::signals::TempWave;
use anyhow::{bail, ensure, Context, Result};
use nalgebra::Vector3;
use rand::Rng;

#[derive(Clone, Debug, PartialEq)]
pub enum HiddenKind {
    /// Field c·I of a current channel (A).
    Current { channel: String },
    /// Field c·dI/dt (inductive coupling) of a current channel.
    CurrentRate { channel: String },
    /// The scalar sensor's time tag lags the fluxgate/GPS by this many seconds.
    Lag { lag_s: f64 },
    /// ε⁶ eddy term eᵀNe·d|B|/dt from flying through gradients.
    Rate,
    /// Fast external variation (micropulsations), also seen by the base station.
    Diurnal,
    /// Cubic induced terms Σ c_ijk e_i e_j e_k |B|/B*.
    InducedHigh,
    /// Large fluxgate calibration errors (the scalar is unchanged).
    FluxCal,
    /// Engine/propeller line driven by an rpm channel.
    Periodic { channel: String },
    /// The fluxgate's bias and scale drift with its temperature, recorded as a channel
    /// (the scalar is unchanged; the direction cosines bend as the temperature moves).
    /// `max_nt_per_degc` is the largest per-axis bias coefficient (0.8 by default).
    FluxTemp {
        channel: String,
        max_nt_per_degc: f64,
    },
    /// The engine's generator coming on line at the take-off's engine start: a body-axis
    /// field (5–20 nT steady, with a decaying transient) with its current optionally
    /// written as a channel (`takeoff.rs`). Part of every take-off; no other flight.
    Engine { channel: Option<String> },
}

#[derive(Clone, Debug, PartialEq)]
pub struct HiddenEffect {
    pub kind: HiddenKind,
    /// Active only for t0 ≤ t < t1 (s) when set.
    pub window_s: Option<(f64, f64)>,
}

impl HiddenEffect {
    /// Name used in `truth_hidden_<name>`.
    pub fn name(&self) -> String {
        match &self.kind {
            HiddenKind::Current { channel } => format!("current_{channel}"),
            HiddenKind::CurrentRate { channel } => format!("current_rate_{channel}"),
            HiddenKind::Lag { .. } => "lag".into(),
            HiddenKind::Rate => "rate".into(),
            HiddenKind::Diurnal => "diurnal".into(),
            HiddenKind::InducedHigh => "induced_high".into(),
            HiddenKind::FluxCal => "fluxcal".into(),
            HiddenKind::Periodic { channel } => format!("periodic_{channel}"),
            HiddenKind::FluxTemp { channel, .. } => format!("fluxtemp_{channel}"),
            HiddenKind::Engine { .. } => "engine".into(),
        }
    }
    pub fn column(&self) -> String {
        format!("truth_hidden_{}", self.name())
    }
    pub fn active(&self, t: f64) -> bool {
        self.window_s.is_none_or(|(a, b)| t >= a && t < b)
    }
    /// The auxiliary channel this effect writes, if any.
    pub fn channel(&self) -> Option<&str> {
        match &self.kind {
            HiddenKind::Current { channel }
            | HiddenKind::CurrentRate { channel }
            | HiddenKind::Periodic { channel }
            | HiddenKind::FluxTemp { channel, .. } => Some(channel),
            HiddenKind::Engine { channel } => channel.as_deref(),
            _ => None,
        }
    }
}

/// The fluxgate's temperature drift: its reading `F` becomes `F + d·β` with `d = T − T(0)`
/// and β within K/4…K nT/°C per axis, random signs (K the largest coefficient; default
/// 0.8, the 0.2–0.8 nT/°C of issue 12). A bias drift only: a scale drift is part of the
/// `fluxtemp` fit, but on a cloverleaf its three coefficients are poorly determined (the
/// field stays near one body axis), so a simulated one would test that conditioning rather
/// than the diagnosis.
#[derive(Clone, Debug)]
pub struct FluxTempDrift {
    pub temp: TempWave,
    pub bias_nt_per_degc: Vector3<f64>,
}

impl FluxTempDrift {
    pub fn random<R: Rng>(max_nt_per_degc: f64, rng: &mut R) -> Self {
        let k = max_nt_per_degc;
        let mut signed = || {
            let s = if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
            s * rng.gen_range(k / 4.0..k)
        };
        let bias = Vector3::new(signed(), signed(), signed());
        FluxTempDrift {
            temp: TempWave::random(rng),
            bias_nt_per_degc: bias,
        }
    }
    /// The drifted reading at time `t` (the drift's rate is d'·β).
    pub fn apply(
        &self,
        t: f64,
        f: &Vector3<f64>,
        f_dot: &Vector3<f64>,
    ) -> (Vector3<f64>, Vector3<f64>) {
        let (temp, temp_dot) = self.temp.eval(t);
        let d = temp - self.temp.eval(0.0).0;
        (
            f + self.bias_nt_per_degc * d,
            f_dot + self.bias_nt_per_degc * temp_dot,
        )
    }
}

/// Checks an auxiliary channel name: a CSV-safe identifier that is not a standard column.
pub fn check_channel(ch: &str) -> Result<()> {
    ensure!(!ch.is_empty(), "empty channel name");
    ensure!(
        ch.chars().all(|c| c.is_ascii_alphanumeric() || c == '_'),
        "channel name `{ch}` may only contain letters, digits and `_`"
    );
    const RESERVED: [&str; 17] = [
        "t", "mag", "flux_x", "flux_y", "flux_z", "lat", "lon", "alt", "vn", "ve", "vd", "roll",
        "pitch", "yaw", "base", "igrf", "segment",
    ];
    ensure!(
        !RESERVED.contains(&ch) && !ch.starts_with("truth_"),
        "channel name `{ch}` clashes with a standard column"
    );
    Ok(())
}

/// Parses `KIND[:ARG][@T0:T1]`, e.g. `current:cur_pump`, `lag:0.1@600:1200`, `rate`.
pub fn parse_hidden(spec: &str) -> Result<HiddenEffect> {
    let spec = spec.trim();
    let (body, window) = match spec.split_once('@') {
        Some((b, w)) => {
            let (a, c) = w
                .split_once(':')
                .with_context(|| format!("window `{w}` must be T0:T1 (seconds)"))?;
            let t0: f64 = a
                .trim()
                .parse()
                .with_context(|| format!("bad window start `{a}`"))?;
            let t1: f64 = c
                .trim()
                .parse()
                .with_context(|| format!("bad window end `{c}`"))?;
            ensure!(
                t0.is_finite() && t1.is_finite() && t0 >= 0.0 && t1 > t0,
                "window must satisfy 0 ≤ T0 < T1"
            );
            (b, Some((t0, t1)))
        }
        None => (spec, None),
    };
    let (kind, arg) = match body.split_once(':') {
        Some((k, a)) => (k.trim(), Some(a.trim())),
        None => (body.trim(), None),
    };
    let need_ch = |a: Option<&str>| -> Result<String> {
        let ch =
            a.with_context(|| format!("`{kind}` needs a channel name, e.g. `{kind}:cur_pump`"))?;
        check_channel(ch)?;
        Ok(ch.to_string())
    };
    let no_arg = |a: Option<&str>| -> Result<()> {
        ensure!(a.is_none(), "`{kind}` takes no argument");
        Ok(())
    };
    let kind = match kind {
        "current" => HiddenKind::Current {
            channel: need_ch(arg)?,
        },
        "current_rate" => HiddenKind::CurrentRate {
            channel: need_ch(arg)?,
        },
        "periodic" => HiddenKind::Periodic {
            channel: need_ch(arg)?,
        },
        "fluxtemp" => {
            // `fluxtemp:CH` or `fluxtemp:CH:K` (K: largest bias coefficient, nT/°C).
            let (ch, k) = match arg.map(|a| a.split_once(':')) {
                Some(Some((c, k))) => {
                    let k: f64 = k
                        .trim()
                        .parse()
                        .with_context(|| format!("bad fluxgate temperature coefficient `{k}`"))?;
                    ensure!(
                        k.is_finite() && k > 0.0 && k <= 100.0,
                        "the fluxgate temperature coefficient must be within (0, 100] nT/°C"
                    );
                    (Some(c.trim()), k)
                }
                _ => (arg, 0.8),
            };
            HiddenKind::FluxTemp {
                channel: need_ch(ch)?,
                max_nt_per_degc: k,
            }
        }
        "lag" => {
            let a = arg.context("`lag` needs the lag in seconds, e.g. `lag:0.1`")?;
            let lag_s: f64 = a.parse().with_context(|| format!("bad lag `{a}`"))?;
            ensure!(
                lag_s.is_finite() && lag_s > 0.0 && lag_s <= 2.0,
                "lag must be within (0, 2] s"
            );
            HiddenKind::Lag { lag_s }
        }
        "engine" => HiddenKind::Engine {
            channel: arg.map(|a| need_ch(Some(a))).transpose()?,
        },
        "rate" => {
            no_arg(arg)?;
            HiddenKind::Rate
        }
        "diurnal" => {
            no_arg(arg)?;
            HiddenKind::Diurnal
        }
        "induced_high" => {
            no_arg(arg)?;
            HiddenKind::InducedHigh
        }
        "fluxcal" => {
            no_arg(arg)?;
            HiddenKind::FluxCal
        }
        other => bail!(
            "unknown hidden effect `{other}` (known: current:CH, current_rate:CH, lag:SECONDS, rate, diurnal, induced_high, fluxcal, periodic:CH, fluxtemp:CH, engine[:CH])"
        ),
    };
    Ok(HiddenEffect {
        kind,
        window_s: window,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_specs() {
        let h = parse_hidden("current:cur_pump@100:400").unwrap();
        assert_eq!(
            h.kind,
            HiddenKind::Current {
                channel: "cur_pump".into()
            }
        );
        assert_eq!(h.window_s, Some((100.0, 400.0)));
        assert_eq!(h.column(), "truth_hidden_current_cur_pump");
        assert_eq!(
            parse_hidden("lag:0.1").unwrap().kind,
            HiddenKind::Lag { lag_s: 0.1 }
        );
        assert_eq!(parse_hidden("rate").unwrap().kind, HiddenKind::Rate);
        assert_eq!(
            parse_hidden("engine").unwrap().kind,
            HiddenKind::Engine { channel: None }
        );
        let e = parse_hidden("engine:cur_alt").unwrap();
        assert_eq!(
            (e.name().as_str(), e.channel()),
            ("engine", Some("cur_alt"))
        );
        let ft = parse_hidden("fluxtemp:temp_flux").unwrap();
        assert_eq!(ft.name(), "fluxtemp_temp_flux");
        assert_eq!(ft.channel(), Some("temp_flux"));
        assert_eq!(
            parse_hidden("fluxtemp:temp_flux:4").unwrap().kind,
            HiddenKind::FluxTemp {
                channel: "temp_flux".into(),
                max_nt_per_degc: 4.0
            }
        );
        for bad in [
            "",
            "foo",
            "current",
            "lag:x",
            "lag:-1",
            "rate:3",
            "current:a b",
            "current:mag",
            "diurnal@5:1",
            "fluxcal@a:b",
            "fluxtemp",
            "fluxtemp:t x",
            "fluxtemp:t:0",
            "fluxtemp:t:x",
            "engine:mag",
        ] {
            assert!(parse_hidden(bad).is_err(), "{bad}");
        }
    }
}
