//! The coefficient store's images on the host (`src/store.rs`, the board's own code): every
//! sensor's coefficients saved and loaded, and an image written before sensors 1–2
//! (`MCS2`) still loaded, its sensors 1–2 calibrating.

use hil_tests::board_config::{self, BoardAcquisition, N_COEF, Staged};
use hil_tests::store;
use magcomp_core::model::Model;
use magcomp_core::protocol::command::{FLUX_CAL_LEN, FLUX_TEMP_LEN, blob_len};
use magcomp_core::protocol::common::crc32;

fn acquisition() -> Box<BoardAcquisition> {
    let mut acq = Box::new(BoardAcquisition::placeholder(Model {
        field: false,
        terms: &[],
    }));
    board_config::start(&mut acq).unwrap();
    acq
}

fn set(v: f32) -> [f32; N_COEF] {
    core::array::from_fn(|i| v + i as f32 * 0.25)
}

fn coefficients(acq: &BoardAcquisition, sensor: usize) -> [f32; N_COEF] {
    let mut c = [0.0; N_COEF];
    acq.sensor(sensor).unwrap().coefficients(&mut c);
    c
}

/// Values held within 2 ulp (the filter keeps scaled states).
fn close(a: &[f32; N_COEF], b: &[f32; N_COEF]) -> bool {
    a.iter()
        .zip(b)
        .all(|(x, y)| (x - y).abs() <= 2.0 * f32::EPSILON * y.abs().max(1.0))
}

#[test]
fn every_sensor_is_saved_and_an_image_from_before_sensors_1_and_2_still_loads() {
    let acq = acquisition();
    let staged: Staged = [Some(set(1.0)), Some(set(-2.0)), Some(set(3.5))];
    let mut img = store::ERASED;
    store::seal(7, &acq, &staged, &mut img).unwrap();
    assert_eq!(&img[..4], b"MCS3");
    assert_eq!(store::sequence(&img), Some(7));
    let mut back = acquisition();
    store::load_image(&img, &mut back).unwrap();
    for (s, want) in staged.iter().enumerate() {
        let got = coefficients(&back, s);
        assert!(close(&got, want.as_ref().unwrap()), "sensor {s}: {got:?}");
        assert!(back.sensor(s).unwrap().is_survey_mode(), "sensor {s}");
    }
    // one flipped byte in sensor 2's blob: the image fails its CRC
    let mut bad = img;
    bad[store::IMAGE_LEN - 20] ^= 1;
    assert_eq!(store::sequence(&bad), None);

    // the same first four blobs as an `MCS2` image: its CRC after them, erased flash beyond
    let v2 = blob_len(N_COEF) + blob_len(FLUX_CAL_LEN) + blob_len(1) + blob_len(FLUX_TEMP_LEN);
    let mut old = store::ERASED;
    old[..8 + v2].copy_from_slice(&img[..8 + v2]);
    old[..4].copy_from_slice(b"MCS2");
    let crc = crc32(&old[..8 + v2]);
    old[8 + v2..12 + v2].copy_from_slice(&crc.to_le_bytes());
    assert_eq!(store::sequence(&old), Some(7));
    let mut back = acquisition();
    store::load_image(&old, &mut back).unwrap();
    assert!(close(&coefficients(&back, 0), &set(1.0)));
    assert!(back.sensor(0).unwrap().is_survey_mode());
    for s in [1, 2] {
        assert!(
            !back.sensor(s).unwrap().is_survey_mode(),
            "sensor {s} calibrates"
        );
        assert!(!close(&coefficients(&back, s), staged[s].as_ref().unwrap()));
    }
    // the old layout's CRC where the new one expects it fails: never read as `MCS3`
    old[..4].copy_from_slice(b"MCS3");
    assert_eq!(store::sequence(&old), None);
}
