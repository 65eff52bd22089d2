//! `magcomp upload`: a `calibrate` JSON as the board's command lines — `SETCOEF` for every
//! coefficient, `SETFLUX` for the fluxgate calibration (`fluxcal`), `SETLAG` for the
//! scalar's delay (`lag`; 0 without it, so an earlier upload's τ does not stay),
//! `SETFTEMP` for the fluxgate's temperature drift (`fluxtemp`; all zero without it), then
//! `SAVE` — written to the board's port (or stdout), so coefficients reach the aircraft
//! without a rebuild.

use crate::calibration::coefficients::{Coefficient, CoefficientFile, Method};
use crate::model::spec::{InputCorrection, ModelSpec};
use anyhow::{bail, Context, Result};
use magcomp_core::model::TermKind;
use magcomp_core::protocol::command::{encode_command, Command, MAX_COEF_ABS, MAX_SENSORS};
use magcomp_core::protocol::fluxgate::FluxTempCal;
use magcomp_core::protocol::lag_line::MAX_LAG_S;

/// The command lines for a coefficient file, `SAVE` last unless `save` is false.
pub fn upload_lines(file: &CoefficientFile, board_model: &str, save: bool) -> Result<Vec<String>> {
    let mut buf = [0u8; 96];
    upload_commands(file, board_model, save)?
        .iter()
        .map(|c| {
            let n = encode_command(c, &mut buf).context("command line too long")?;
            Ok(String::from_utf8_lossy(&buf[..n]).into_owned())
        })
        .collect()
}

/// `file` with the board's `fluxmod` coefficient added as exactly 0 (and, in a covariance, a
/// row and column of zeros: it is not estimated).
fn with_witness_zero(file: &CoefficientFile, board: &ModelSpec) -> Result<CoefficientFile> {
    let (name, unit) = board
        .coefficient_names()
        .into_iter()
        .find(|(n, _)| n.starts_with(TermKind::FluxMod.name()))
        .context("the board's model has no fluxmod coefficient")?;
    let mut out = file.clone();
    out.coefficients.push(Coefficient {
        name,
        unit,
        value: 0.0,
        sigma: 0.0,
    });
    if let Some(cov) = out.covariance.as_mut() {
        let k = cov.len() + 1;
        cov.iter_mut().for_each(|row| row.push(0.0));
        cov.push(vec![0.0; k]);
    }
    Ok(out)
}

/// The commands for a coefficient file, `SAVE` last unless `save` is false.
pub fn upload_commands(
    file: &CoefficientFile,
    board_model: &str,
    save: bool,
) -> Result<Vec<Command>> {
    if file.method != Method::Kf {
        bail!("Tolles–Lawson coefficients cannot be loaded into the board's filter: calibrate with --method kf");
    }
    let board = ModelSpec::parse(board_model)?;
    let theirs = ModelSpec::parse(&file.model)?;
    // `fluxtemp`: the board corrects each fluxgate frame with the temperature on its line
    // (4th field) before `fluxcal`, as the host does before calibrating.
    let flux_temp = if theirs.corrects(InputCorrection::FluxTemp) {
        let c = file.fluxgate_temperature.as_ref().with_context(|| {
            format!(
                "the coefficients are for model '{}' but the file holds no fluxgate_temperature",
                theirs.text()
            )
        })?;
        crate::board::replay::board_flux_temperature(c)?
    } else {
        FluxTempCal::NONE
    };
    // `lag`: the board delays the fluxgate by τ (SETLAG) instead of re-aligning the scalar.
    let lag_s = if theirs.corrects(InputCorrection::Lag) {
        let l = file.scalar_lag.with_context(|| {
            format!(
                "the coefficients are for model '{}' but the file holds no scalar_lag (τ)",
                theirs.text()
            )
        })?;
        if !(0.0..=f64::from(MAX_LAG_S)).contains(&l.lag_s) {
            bail!(
                "the scalar's delay τ = {:.4} s is outside what the board can apply (0 – {MAX_LAG_S} s: it delays the fluxgate, so the scalar must lag it)",
                l.lag_s
            );
        }
        l.lag_s as f32
    } else {
        0.0
    };
    // `fluxcal`, `lag` and `fluxtemp` add no filter state: their coefficients are the board model's.
    let without_fluxcal = theirs.without_input_corrections();
    // A board whose vector is its model's witnessed form takes a set of its model with
    // `fluxmod` = 0 (the paper filter's records are then shown).
    let padded;
    let file = if board.has(TermKind::FluxMod)
        && !without_fluxcal.has(TermKind::FluxMod)
        && without_fluxcal.with(TermKind::FluxMod.name())?.text() == board.text()
    {
        padded = with_witness_zero(file, &board)?;
        &padded
    } else {
        if without_fluxcal.text() != board.text() {
            bail!(
                "the coefficients are for model '{}', the board runs '{}'",
                theirs.text(),
                board.text()
            );
        }
        file
    };
    // Every coefficient the board's model has, by name, and nothing else: SETCOEF
    // indices are the board's, so a short, long or reordered file must not reach it.
    let names: Vec<String> = board
        .coefficient_names()
        .into_iter()
        .map(|(n, _)| n)
        .collect();
    let file = &file.in_order_of(&names).with_context(|| {
        format!(
            "the coefficients do not fit the board's model '{}' ({} coefficients)",
            board.text(),
            names.len()
        )
    })?;
    // The crossover rate fit (post-flight, `rate`): its five anisotropic coefficients add
    // to the board's `rate` term; the isotropic one has no board coefficient (see
    // `run_upload`).
    let crossover = file.rate_crossover.as_ref().filter(|r| r.applied);
    let mut cmds: Vec<Command> = Vec::new();
    for (i, c) in file.coefficients.iter().enumerate() {
        let extra = crossover
            .and_then(|r| {
                // A coefficient file names a coefficient `term.label`.
                let label = c
                    .name
                    .strip_prefix(TermKind::Rate.name())?
                    .strip_prefix('.')?;
                let k = crate::estimate::crossover::RATE_LABELS[..5]
                    .iter()
                    .position(|l| *l == label)?;
                Some(r.fit.coefficients[k])
            })
            .unwrap_or(0.0);
        let value = (c.value + extra) as f32;
        if !value.is_finite() || value.abs() >= MAX_COEF_ABS {
            bail!(
                "coefficient {i} ({}) = {} is out of the board's range",
                c.name,
                c.value
            );
        }
        cmds.push(Command::SetCoef {
            index: i as u16,
            value,
        });
    }
    if let Some(cal) = &file.fluxgate_calibration {
        // The board's own bounds are only those of a working sensor; a fit from bad data
        // (−38,736 nT bias, z scale 1.75) passed them.
        if let Some(problem) = cal.physical_problem() {
            anyhow::bail!("{problem}: not uploaded (recalibrate on clean data)");
        }
        let board = cal.to_board().context(
            "the fluxgate calibration is not a plausible one (diagonal 0.5–2, off-diagonal ±0.5, bias ±100 000 nT)",
        )?;
        for (i, value) in board.to_array().into_iter().enumerate() {
            cmds.push(Command::SetFlux {
                index: i as u16,
                value,
            });
        }
    }
    cmds.push(Command::SetLag(lag_s));
    // Always all 7: zeros clear an earlier upload's correction.
    for (i, value) in flux_temp.to_array().into_iter().enumerate() {
        cmds.push(Command::SetFluxTemp {
            index: i as u16,
            value,
        });
    }
    if save {
        cmds.push(Command::Save);
    }
    Ok(cmds)
}

/// The commands for a several-sensor coefficient file (`calibrate --sensors`), its sensors
/// in the file's order being the counter line's channels 0, 1, 2: every sensor's
/// coefficients (`SETCOEF,<sensor>,…`; sensor 0's in the single-sensor form), and the
/// fluxgate's corrections from sensor 0's file (the board has one fluxgate), `SAVE` last
/// unless `save` is false.
pub fn sensor_commands(
    files: &[CoefficientFile],
    board_model: &str,
    save: bool,
) -> Result<Vec<Command>> {
    if files.is_empty() || files.len() > MAX_SENSORS {
        bail!(
            "the file holds {} sensors; the board's counter line carries 1–{MAX_SENSORS}",
            files.len()
        );
    }
    // The board runs the witness in channel 1's compensator, which a second sensor needs.
    if let Some(f) = files
        .iter()
        .find(|f| ModelSpec::parse(&f.model).is_ok_and(|m| m.has(TermKind::FluxMod)))
    {
        bail!(
            "model '{}' takes the fluxgate as a witness (`fluxmod`), which the board runs for a \
             single magnetometer only: calibrate the several sensors with `--method kf`",
            f.model
        );
    }
    let mut cmds = upload_commands(&files[0], board_model, false)?;
    for (sensor, f) in files.iter().enumerate().skip(1) {
        let theirs =
            upload_commands(f, board_model, false).with_context(|| format!("sensor {sensor}"))?;
        cmds.extend(theirs.into_iter().filter_map(|c| match c {
            Command::SetCoef { index, value } => Some(Command::SetSensorCoef {
                sensor: sensor as u8,
                index,
                value,
            }),
            _ => None,
        }));
    }
    if save {
        cmds.push(Command::Save);
    }
    Ok(cmds)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::coefficients::Coefficient;
    use crate::estimate::fluxcal::FluxgateCalibration;
    use magcomp_core::protocol::command::parse_command;

    /// A file for `model` with `n` coefficients named as the model names them (`c{i}`
    /// past the model's count).
    fn file(model: &str, n: usize, flux: Option<FluxgateCalibration>) -> CoefficientFile {
        let names = ModelSpec::parse(model).unwrap().coefficient_names();
        let coefficients = (0..n)
            .map(|i| Coefficient {
                name: names.get(i).map_or(format!("c{i}"), |n| n.0.clone()),
                unit: "nT".into(),
                value: (i as f64 - 7.5) * 3.25e-2,
                sigma: 0.1,
            })
            .collect();
        CoefficientFile {
            fluxgate_calibration: flux,
            ..CoefficientFile::new(model, Method::Kf, 10.0, coefficients)
        }
    }

    #[test]
    fn a_several_sensor_file_with_a_witnessed_set_is_refused() {
        let paper = file("tl16+field", 16, None);
        let witnessed = file("tl16+field+fluxmod", 17, None);
        let board = crate::model::spec::BOARD_COEFFICIENTS;
        let e = sensor_commands(&[witnessed, paper.clone()], board, true).unwrap_err();
        assert!(e.to_string().contains("single magnetometer"), "{e}");
        assert!(sensor_commands(&[paper.clone(), paper], board, true).is_ok());
    }

    #[test]
    fn a_several_sensor_file_sends_each_sensor_to_its_channel() {
        let f = |v: f64| {
            let mut x = file("tl16+field", 16, None);
            x.coefficients[3].value = v;
            x
        };
        let cmds = sensor_commands(&[f(1.0), f(2.0), f(3.0)], "tl16+field", true).unwrap();
        // sensor 0 as a single file (16 SETCOEF, SETLAG, 7 SETFTEMP), 16 for each other, SAVE
        assert_eq!(cmds.len(), 16 + 1 + 7 + 16 + 16 + 1);
        assert_eq!(
            cmds[3],
            Command::SetCoef {
                index: 3,
                value: 1.0
            }
        );
        for sensor in [1u8, 2] {
            let mine: Vec<(u16, f32)> = cmds
                .iter()
                .filter_map(|c| match *c {
                    Command::SetSensorCoef {
                        sensor: s,
                        index,
                        value,
                    } if s == sensor => Some((index, value)),
                    _ => None,
                })
                .collect();
            assert_eq!(mine.len(), 16);
            assert_eq!(mine[3], (3, f32::from(sensor) + 1.0));
        }
        assert_eq!(cmds.last(), Some(&Command::Save));
        let lines: Vec<String> = cmds
            .iter()
            .map(|c| {
                let mut b = [0u8; 96];
                let n = encode_command(c, &mut b).unwrap();
                String::from_utf8_lossy(&b[..n]).into_owned()
            })
            .collect();
        assert!(lines.iter().any(|l| l.starts_with("$MCCMD,SETCOEF,2,3,")));
        let four: Vec<_> = (0..4).map(|_| f(1.0)).collect();
        assert!(sensor_commands(&four, "tl16+field", true).is_err());
        assert!(sensor_commands(&[], "tl16+field", true).is_err());
    }

    #[test]
    fn an_applied_crossover_rate_fit_adds_to_the_board_rate_coefficients() {
        let mut f = file("tl16+field+rate", 21, None);
        for (k, c) in f.coefficients[16..].iter_mut().enumerate() {
            c.name = format!("rate.{}", crate::estimate::crossover::RATE_LABELS[k]);
            c.value = 0.001 * k as f64;
        }
        let fit = crate::estimate::crossover::RateFit {
            coefficients: [0.01, 0.02, 0.03, 0.04, 0.05, 0.06],
            sigmas: [0.0; 6],
            crossings: 40,
            rms_before_nt: 0.1,
            rms_after_nt: 0.02,
            f_statistic: 50.0,
            p_value: 1e-20,
            added_parameters: 6,
        };
        for applied in [true, false] {
            // 21 SETCOEF, then SETLAG 0 and 7 × SETFTEMP 0
            f.rate_crossover = Some(crate::calibration::coefficients::RateCrossover {
                labels: crate::estimate::crossover::RATE_LABELS
                    .map(String::from)
                    .to_vec(),
                fit: fit.clone(),
                applied,
            });
            let lines = upload_lines(&f, "tl16+field+rate", false).unwrap();
            assert_eq!(lines.len(), 21 + 1 + 7);
            for (k, l) in lines[16..21].iter().enumerate() {
                let Ok(Command::SetCoef { index, value }) = parse_command(l.as_bytes(), 21) else {
                    panic!("{l}");
                };
                assert_eq!(index as usize, 16 + k);
                let want = 0.001 * k as f64 + if applied { fit.coefficients[k] } else { 0.0 };
                assert_eq!(value, want as f32, "applied {applied}, {l}");
            }
        }
    }

    #[test]
    fn every_line_parses_back_to_the_file_values() {
        let cal = FluxgateCalibration {
            matrix: [
                [1.006, 0.002, -0.001],
                [0.002, 0.993, 0.0015],
                [-0.001, 0.0015, 1.004],
            ],
            bias_nt: [320.5, -250.25, 410.0],
        };
        let f = file("tl16+field+fluxcal", 16, Some(cal));
        let lines = upload_lines(&f, "tl16+field", true).unwrap();
        assert_eq!(lines.len(), 16 + 12 + 1 + 7 + 1);
        let mut coef = [f32::NAN; 16];
        let mut flux = [f32::NAN; 12];
        let mut lag = f32::NAN;
        let mut ftemp = [f32::NAN; 7];
        for l in &lines[..lines.len() - 1] {
            match parse_command(l.as_bytes(), 16).unwrap() {
                Command::SetCoef { index, value } => coef[index as usize] = value,
                Command::SetFlux { index, value } => flux[index as usize] = value,
                Command::SetLag(v) => lag = v,
                Command::SetFluxTemp { index, value } => ftemp[index as usize] = value,
                c => panic!("unexpected {c:?}"),
            }
        }
        // No `lag` in the model: τ = 0, so an earlier upload's delay does not stay.
        assert_eq!(lag, 0.0);
        // No `fluxtemp`: the correction cleared.
        assert_eq!(ftemp, [0.0; 7]);
        assert_eq!(
            parse_command(lines.last().unwrap().as_bytes(), 16),
            Ok(Command::Save)
        );
        for (i, c) in f.coefficients.iter().enumerate() {
            assert_eq!(coef[i], c.value as f32);
        }
        assert_eq!(flux[0], 1.006f32);
        assert_eq!(flux[9], 320.5);
        assert_eq!(flux[11], 410.0);
    }

    /// `lag` → the board model plus `SETLAG τ` (the board delays the fluxgate); a τ the
    /// board cannot apply (negative: the scalar leads; beyond 0.5 s) or a missing one is
    /// refused.
    #[test]
    fn a_lag_file_sends_setlag_and_an_impossible_lag_is_refused() {
        let with = |lag_s: Option<f64>| {
            let mut f = file("tl16+field+lag", 16, None);
            f.scalar_lag = lag_s.map(|lag_s| crate::model::corrections::ScalarLag {
                lag_s,
                sigma_s: 0.0012,
            });
            upload_lines(&f, "tl16+field", true)
        };
        let lines = with(Some(0.2048)).unwrap();
        assert_eq!(lines.len(), 16 + 1 + 7 + 1);
        assert_eq!(
            parse_command(lines[16].as_bytes(), 16),
            Ok(Command::SetLag(0.2048))
        );
        assert_eq!(parse_command(lines[24].as_bytes(), 16), Ok(Command::Save));
        assert!(with(Some(0.5)).is_ok());
        for (lag, needle) in [
            (Some(-0.05), "outside what the board can apply"),
            (Some(0.6), "outside what the board can apply"),
            (None, "holds no scalar_lag"),
        ] {
            let e = with(lag).unwrap_err();
            assert!(format!("{e:#}").contains(needle), "{lag:?}: {e:#}");
        }
    }

    /// `fluxtemp` → the board model plus 7 `SETFTEMP` (T_ref, b, s); a file without the
    /// correction, or with an absurd one, is refused.
    #[test]
    fn a_fluxtemp_file_sends_setftemp() {
        let with = |c: Option<crate::model::corrections::FluxgateTemperature>| {
            let mut f = file("tl16+field+fluxtemp:temp_flux", 16, None);
            f.fluxgate_temperature = c;
            upload_lines(&f, "tl16+field", true)
        };
        let c = crate::model::corrections::FluxgateTemperature {
            channel: "temp_flux".into(),
            reference_degc: 21.5,
            bias_nt_per_degc: [0.41, -0.2, 0.8],
            bias_sigma_nt_per_degc: [0.01; 3],
            scale_per_degc: [1e-5, -2e-5, 3e-6],
            scale_sigma_per_degc: [1e-6; 3],
        };
        let lines = with(Some(c.clone())).unwrap();
        assert_eq!(lines.len(), 16 + 1 + 7 + 1);
        let sent: Vec<Command> = lines[17..24]
            .iter()
            .map(|l| parse_command(l.as_bytes(), 16).unwrap())
            .collect();
        let want = [21.5, 0.41, -0.2, 0.8, 1e-5, -2e-5, 3e-6];
        for (i, cmd) in sent.iter().enumerate() {
            assert_eq!(
                *cmd,
                Command::SetFluxTemp {
                    index: i as u16,
                    value: want[i] as f32
                }
            );
        }
        let e = with(None).unwrap_err();
        assert!(
            format!("{e:#}").contains("no fluxgate_temperature"),
            "{e:#}"
        );
        let mut absurd = c;
        absurd.scale_per_degc[1] = 0.5;
        let e = with(Some(absurd)).unwrap_err();
        assert!(format!("{e:#}").contains("not a plausible"), "{e:#}");
    }

    #[test]
    fn both_the_paper_and_the_witnessed_set_load_into_the_boards_vector() {
        let board = crate::model::spec::BOARD_COEFFICIENTS;
        let setcoef = |lines: &[String]| -> Vec<String> {
            lines
                .iter()
                .filter(|l| l.contains("SETCOEF"))
                .cloned()
                .collect()
        };
        // the witnessed set as it is, 17 values
        let witnessed = file("tl16+field+fluxmod", 17, None);
        let w = setcoef(&upload_lines(&witnessed, board, true).unwrap());
        assert_eq!(w.len(), 17);
        // the paper set: its 16 values, then fluxmod exactly 0 (the paper filter is shown)
        let mut paper = file("tl16+field", 16, None);
        paper.covariance = Some(vec![vec![0.01; 16]; 16]);
        let p = setcoef(&upload_lines(&paper, board, true).unwrap());
        assert_eq!(p.len(), 17);
        assert_eq!(p[..16], w[..16], "the same 16 values at the same indices");
        let last = upload_commands(&paper, board, false).unwrap();
        assert!(last.contains(&Command::SetCoef {
            index: 16,
            value: 0.0
        }));
        // a board of the paper model alone (older firmware) refuses the witnessed set
        let e = upload_lines(&witnessed, "tl16+field", true).unwrap_err();
        assert!(format!("{e:#}").contains("board runs"), "{e:#}");
    }

    #[test]
    fn wrong_model_method_or_range_is_refused() {
        let e = upload_lines(
            &file("tl16+field+induced_high", 23, None),
            "tl16+field",
            true,
        )
        .unwrap_err();
        assert!(e.to_string().contains("board runs"), "{e}");
        let mut tl = file("tl16+field", 16, None);
        tl.method = Method::Tl;
        assert!(upload_lines(&tl, "tl16+field", true).is_err());
        let mut big = file("tl16+field", 16, None);
        big.coefficients[3].value = 2e6;
        assert!(upload_lines(&big, "tl16+field", true).is_err());
        let bad = FluxgateCalibration {
            matrix: [[3.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            bias_nt: [0.0; 3],
        };
        assert!(upload_lines(
            &file("tl16+field+fluxcal", 16, Some(bad)),
            "tl16+field",
            true
        )
        .is_err());
        assert_eq!(
            upload_lines(&file("tl16+field", 16, None), "tl16+field", false)
                .unwrap()
                .len(),
            16 + 1 + 7
        );
    }

    #[test]
    fn a_short_long_or_misnamed_file_sends_nothing() {
        // 10 of 16, none (a bare SAVE), 20 (SETCOEF 16–19): refused, naming what is wrong.
        for (n, needle) in [
            (10, "'eddy.e1*de2' is missing (10 of 16 given)"),
            (0, "is missing (0 of 16 given)"),
            (20, "unknown coefficient 'c16'"),
        ] {
            let e = upload_lines(&file("tl16+field", n, None), "tl16+field", true).unwrap_err();
            assert!(format!("{e:#}").contains(needle), "{n}: {e:#}");
        }
        let mut f = file("tl16+field", 16, None);
        f.coefficients[4].name = "induced.wobble".into();
        let e = upload_lines(&f, "tl16+field", true).unwrap_err();
        assert!(
            format!("{e:#}").contains("unknown coefficient 'induced.wobble'"),
            "{e:#}"
        );
    }

    #[test]
    fn swapped_entries_send_the_same_lines() {
        let f = file("tl16+field", 16, None);
        let mut swapped = f.clone();
        swapped.coefficients.swap(2, 9);
        assert_ne!(swapped.coefficients[2].value, f.coefficients[2].value);
        assert_eq!(
            upload_lines(&swapped, "tl16+field", true).unwrap(),
            upload_lines(&f, "tl16+field", true).unwrap()
        );
    }
}
