//! Effects the default compensation model does not know about (`--hidden SPEC`).

use anyhow::{bail, ensure, Context, Result};

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
            | HiddenKind::Periodic { channel } => Some(channel),
            _ => None,
        }
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
        "lag" => {
            let a = arg.context("`lag` needs the lag in seconds, e.g. `lag:0.1`")?;
            let lag_s: f64 = a.parse().with_context(|| format!("bad lag `{a}`"))?;
            ensure!(
                lag_s.is_finite() && lag_s > 0.0 && lag_s <= 2.0,
                "lag must be within (0, 2] s"
            );
            HiddenKind::Lag { lag_s }
        }
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
            "unknown hidden effect `{other}` (known: current:CH, current_rate:CH, lag:SECONDS, rate, diurnal, induced_high, fluxcal, periodic:CH)"
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
        ] {
            assert!(parse_hidden(bad).is_err(), "{bad}");
        }
    }
}
