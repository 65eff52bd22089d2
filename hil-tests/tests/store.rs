//! The coefficient store's images on the host (`src/store.rs`, the board's own code): every
//! sensor's coefficients saved and loaded, an image written before sensors 1–2 (`MCS2`)
//! still loaded, its sensors 1–2 calibrating, and the images of the firmware before the
//! witness (16-value paper sets) loaded as paper sets, `fluxmod` 0.

use hil_tests::board_config::{
    self, BoardAcquisition, CoefSet, FLUXMOD, N_COEF, N_PAPER, NONE_STAGED, Staged, paper_model_id,
};
use hil_tests::store;
use magcomp_core::model::Model;
use magcomp_core::protocol::command::{
    FLUX_CAL_LEN, FLUX_TEMP_LEN, blob_len, encode_blob, flux_blob_id, flux_temp_blob_id,
    lag_blob_id,
};
use magcomp_core::protocol::common::crc32;
use magcomp_core::protocol::fluxgate::FluxCalibration;
use magcomp_core::protocol::lag_line::LagLine;

fn acquisition() -> Box<BoardAcquisition> {
    let mut acq = Box::new(BoardAcquisition::placeholder(Model {
        field: false,
        terms: &[],
    }));
    board_config::start(&mut acq).unwrap();
    // the board's delay line (`fw.rs` attaches it at boot), so a stored τ > 0 applies
    acq.attach_lag_line(Box::leak(Box::new(LagLine::new())));
    acq
}

/// A set of the board's vector; `fluxmod` 0 (a paper set) for sensors 1–2, which run the
/// paper model.
fn set(v: f32, fluxmod: bool) -> CoefSet {
    core::array::from_fn(|i| {
        if i == FLUXMOD && !fluxmod {
            0.0
        } else {
            v + i as f32 * 0.25
        }
    })
}

/// What the board reads back (GETCOEF, SAVE): the shown filter's set for sensor 0.
fn coefficients(acq: &BoardAcquisition, staged: &Staged, sensor: usize) -> CoefSet {
    board_config::coefficients(acq, staged, sensor)
}

/// Values held within 2 ulp (the filter keeps scaled states).
fn close(a: &CoefSet, b: &CoefSet) -> bool {
    a.iter()
        .zip(b)
        .all(|(x, y)| (x - y).abs() <= 2.0 * f32::EPSILON * y.abs().max(1.0))
}

/// An image sealed `seq` from one made with `magic` and `body` (the blobs), CRC after them.
fn image(magic: &[u8; 4], seq: u32, body: &[u8]) -> store::Image {
    let mut img = store::ERASED;
    img[..4].copy_from_slice(magic);
    img[4..8].copy_from_slice(&seq.to_le_bytes());
    img[8..8 + body.len()].copy_from_slice(body);
    let crc = crc32(&img[..8 + body.len()]);
    img[8 + body.len()..12 + body.len()].copy_from_slice(&crc.to_le_bytes());
    img
}

#[test]
fn every_sensor_is_saved_and_an_image_from_before_sensors_1_and_2_still_loads() {
    let acq = acquisition();
    let staged: Staged = [
        Some(set(1.0, false)),
        Some(set(-2.0, false)),
        Some(set(3.5, false)),
    ];
    let mut img = store::ERASED;
    store::seal(7, &acq, &staged, &mut img).unwrap();
    assert_eq!(&img[..4], b"MCS4");
    assert_eq!(store::sequence(&img), Some(7));
    let mut back = acquisition();
    let held = NONE_STAGED;
    store::load_image(&img, &mut back).unwrap();
    // sensor 1's set took channel 1's compensator back from the witness
    assert!(back.witness().is_none());
    for (s, want) in staged.iter().enumerate() {
        let got = coefficients(&back, &held, s);
        assert!(close(&got, want.as_ref().unwrap()), "sensor {s}: {got:?}");
        assert!(back.sensor(s).unwrap().is_survey_mode(), "sensor {s}");
    }
    // one flipped byte in sensor 2's blob: the image fails its CRC
    let mut bad = img;
    bad[store::IMAGE_LEN - 20] ^= 1;
    assert_eq!(store::sequence(&bad), None);

    // the same first four blobs as an `MCS2` image: its CRC after them, erased flash beyond
    let v2 = blob_len(N_COEF) + blob_len(FLUX_CAL_LEN) + blob_len(1) + blob_len(FLUX_TEMP_LEN);
    let mut old = image(b"MCS2", 7, &img[8..8 + v2]);
    assert_eq!(store::sequence(&old), Some(7));
    let mut back = acquisition();
    let held = NONE_STAGED;
    store::load_image(&old, &mut back).unwrap();
    assert!(close(&coefficients(&back, &held, 0), &set(1.0, false)));
    assert!(back.is_survey_mode());
    assert!(
        back.witness().is_some(),
        "no sensor 1 set: the witness runs"
    );
    assert!(
        !back.sensor(2).unwrap().is_survey_mode(),
        "sensor 2 calibrates"
    );
    // the old layout's CRC where the new one expects it fails: never read as `MCS4`
    old[..4].copy_from_slice(b"MCS4");
    assert_eq!(store::sequence(&old), None);
}

/// A board flashed with this firmware may hold the previous firmware's images: 16-value
/// blobs of the paper model (`model_hash(b"tl16+field")` + sensor), `MCS3`, or their
/// blobs alone (the single-image store). Sensor 0's loads as a paper set: the paper
/// filter's, `fluxmod` 0, the witness not shown; sensors 1–2 keep theirs.
#[test]
fn an_image_of_the_firmware_before_the_witness_loads_as_paper_sets() {
    let paper = |v: f32| -> [f32; N_PAPER] { core::array::from_fn(|i| v + i as f32 * 0.25) };
    let sets = [paper(1.0), paper(-2.0), paper(3.5)];
    let mut body = vec![0u8; store::LEN];
    let mut at = 0;
    let mut blob = |id: u32, v: &[f32]| at += encode_blob(id, v, &mut body[at..]).unwrap();
    blob(paper_model_id(), &sets[0]);
    blob(flux_blob_id(), &FluxCalibration::IDENTITY.to_array());
    blob(lag_blob_id(), &[0.2]);
    blob(flux_temp_blob_id(), &[0.0; FLUX_TEMP_LEN]);
    blob(paper_model_id().wrapping_add(1), &sets[1]);
    blob(paper_model_id().wrapping_add(2), &sets[2]);
    let body = &body[..at];
    assert_eq!(
        at + 3 * 4,
        store::LEN,
        "the previous layout: 3 values fewer"
    );
    let want = |s: usize| -> CoefSet {
        let mut c = [0.0; N_COEF];
        c[..N_PAPER].copy_from_slice(&sets[s]);
        c
    };
    let check = |what: &str, back: &BoardAcquisition, held: &Staged| {
        for s in 0..3 {
            let got = coefficients(back, held, s);
            assert!(close(&got, &want(s)), "{what}: sensor {s}: {got:?}");
            assert_eq!(got[FLUXMOD], 0.0, "{what}: sensor {s}");
        }
        assert!(back.is_survey_mode(), "{what}");
        assert!(
            close(
                &{
                    let mut c = [0.0; N_COEF];
                    back.compensator().coefficients(&mut c);
                    c
                },
                &want(0)
            ),
            "{what}: the paper filter holds sensor 0's set"
        );
        assert_eq!(back.lag_s(), 0.2, "{what}: the later slots read");
    };

    let old = image(b"MCS3", 41, body);
    assert_eq!(
        store::sequence(&old),
        Some(41),
        "the previous firmware's image is valid"
    );
    let mut back = acquisition();
    let held = NONE_STAGED;
    store::load_image(&old, &mut back).unwrap();
    check("MCS3", &back, &held);
    // its next `SAVE` writes them in the board's vector, `fluxmod` 0: they read back alike
    let mut img = store::ERASED;
    store::seal(42, &back, &held, &mut img).unwrap();
    let mut again = acquisition();
    let held2 = NONE_STAGED;
    store::load_image(&img, &mut again).unwrap();
    check("resaved", &again, &held2);

    // the single-image store: the same blobs alone at the image's start, no image CRC
    let mut legacy = store::ERASED;
    legacy[..body.len()].copy_from_slice(body);
    let mut back = acquisition();
    let held = NONE_STAGED;
    store::load_legacy(&legacy, &mut back).unwrap();
    check("single image", &back, &held);
}

/// Sensor 0's witnessed set alone is shown from the store; stored beside a set for
/// sensor 1 (an installation of several magnetometers, which needs channel 1's
/// compensator) it cannot run, and sensor 0 calibrates afresh instead of showing a filter
/// frozen beside the witness.
#[test]
fn a_witnessed_set_loads_shown_and_yields_honestly_to_a_second_sensor() {
    let store_of = |sets: [Option<CoefSet>; 3]| {
        let mut img = store::ERASED;
        store::seal(3, &acquisition(), &sets, &mut img).unwrap();
        let mut back = acquisition();
        store::load_image(&img, &mut back).unwrap();
        back
    };
    let alone = store_of([Some(set(1.0, true)), None, None]);
    assert_eq!(
        alone.witness().map(|(_, c)| c.shown()),
        Some(magcomp_core::compensator::witness::Shown::Witness)
    );
    assert!(close(
        &coefficients(&alone, &NONE_STAGED, 0),
        &set(1.0, true)
    ));
    let both = store_of([Some(set(1.0, true)), Some(set(-2.0, false)), None]);
    assert!(both.witness().is_none());
    assert!(!both.is_survey_mode(), "sensor 0 calibrates");
    assert!(both.sensor(1).unwrap().is_survey_mode());
}
