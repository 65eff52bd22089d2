//! The coefficient store's layout, spelled out once: which blobs, in which order, how long,
//! and the two images they are written to alternately. Loading and saving go through
//! [`SLOTS`] only, so adding a blob is one line here.
//!
//! Power-cut safety: the store holds two images (`N_IMAGES`, one flash sector each on the
//! real board), each `IMAGE_MAGIC`, a sequence number, the blobs, and a CRC-32 over all of
//! it. `SAVE` writes the image that is *not* the newest valid one, with the next sequence
//! number, and reads it back; a cut at any point of it leaves the other image intact, and
//! boot loads the valid image with the highest sequence number: the old set or the new,
//! never a mix.
//!
//! Each slot is a core blob (`magcomp_core::protocol::command::{encode,decode}_blob`: magic,
//! version, count, id, values, CRC-32). A store written before a later slot existed loads
//! that slot's default (no fluxgate calibration / τ = 0 / no temperature drift / sensors 1
//! and 2 calibrate).
//!
//! Sensors 1 and 2 (the counter line's channels, `SETCOEF,<sensor>,…`) were added after the
//! four first slots, at the end: an image written before them (`MCS2`, its CRC after the
//! four) is the new layout's prefix and still loads, its sensors 1–2 calibrating.
//!
//! The sets became the witnessed model's 17 values (`board_config::MODEL_SPEC`) when the
//! board started running the witness beside the paper model; new images say `MCS4`. Earlier
//! firmware's images (`MCS3`, `MCS2`) hold the paper model's 16 values (id
//! `board_config::PAPER_SPEC`), or with its `flux-witness` build the 17 of today: [`Form`];
//! which one an image holds, its CRC's place says ([`LAYOUTS`]). A paper set loads with
//! `fluxmod` 0.
//!
//! Where the images are is the board's business (`board_shape::CoefStore`): on the real
//! board the 16 KiB flash sectors 1 and 2. Earlier firmware kept them in the 128 KiB
//! sectors 10 and 11 ([`N_OLD_IMAGES`], and before the two images a single store of blobs
//! alone at the start of sector 11: [`load_legacy`]); boot reads those only when neither
//! current image is valid, so an upgraded board keeps its calibration until its next `SAVE`.

use magcomp_core::protocol::command::{
    FLUX_CAL_LEN, FLUX_TEMP_LEN, blob_len, decode_blob, encode_blob, flux_blob_id,
    flux_temp_blob_id, lag_blob_id,
};
use magcomp_core::protocol::fluxgate::{FluxCalibration, FluxTempCal};

use magcomp_core::protocol::common::crc32;

use crate::board_config::{
    self as bc, BoardAcquisition, FLUX_HAS_TEMPERATURE, N_COEF, N_PAPER, Staged, model_id,
    paper_model_id,
};

/// One blob of the store.
#[derive(Clone, Copy)]
pub enum Slot {
    /// Sensor n's coefficients (`SETCOEF`); without sensor 0's the board calibrates, without
    /// sensor 1's or 2's that sensor does.
    Model(u8),
    /// The fluxgate's scalar calibration (`SETFLUX`).
    FluxCal,
    /// The scalar's delay τ (`SETLAG`).
    Lag,
    /// The fluxgate's temperature drift (`SETFTEMP`).
    FluxTemp,
}

/// The store, in order.
pub const SLOTS: [Slot; 6] = [
    Slot::Model(0),
    Slot::FluxCal,
    Slot::Lag,
    Slot::FluxTemp,
    Slot::Model(1),
    Slot::Model(2),
];

/// Slots of an `MCS2` image (before sensors 1–2).
const SLOTS_V2: usize = 4;

/// How an image holds the sensors' sets.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Form {
    /// The board's vector: the witnessed model's 17 values (`MODEL_SPEC`'s id).
    Board,
    /// Earlier firmware's paper model alone: 16 values (`PAPER_SPEC`'s id).
    Paper,
}

impl Form {
    const fn values(self) -> usize {
        match self {
            Form::Board => N_COEF,
            Form::Paper => N_PAPER,
        }
    }
}

/// Bytes of the first `n` slots with the sets in `form`.
const fn slots_len(n: usize, form: Form) -> usize {
    let mut len = 0;
    let mut i = 0;
    while i < n {
        len += blob_len(SLOTS[i].values_in(form));
        i += 1;
    }
    len
}

/// Bytes of the whole store.
pub const LEN: usize = slots_len(SLOTS.len(), Form::Board);

/// Largest slot (values): the scratch array `save`/`load` use.
const MAX_VALUES: usize = {
    let mut m = 0;
    let mut i = 0;
    while i < SLOTS.len() {
        if SLOTS[i].values() > m {
            m = SLOTS[i].values();
        }
        i += 1;
    }
    m
};

impl Slot {
    /// Values held.
    pub const fn values(self) -> usize {
        self.values_in(Form::Board)
    }

    /// Values held in an image whose sets are in `form`.
    const fn values_in(self, form: Form) -> usize {
        match self {
            Slot::Model(_) => form.values(),
            Slot::FluxCal => FLUX_CAL_LEN,
            Slot::Lag => 1,
            Slot::FluxTemp => FLUX_TEMP_LEN,
        }
    }

    fn id(self, form: Form) -> u32 {
        let model = match form {
            Form::Board => model_id(),
            Form::Paper => paper_model_id(),
        };
        match self {
            // sensor n's blob: the model's id plus n, so blobs never stand in for each other
            Slot::Model(n) => model.wrapping_add(n.into()),
            Slot::FluxCal => flux_blob_id(),
            Slot::Lag => lag_blob_id(),
            Slot::FluxTemp => flux_temp_blob_id(),
        }
    }

    /// The acquisition's current values for this slot (a sensor's are `staged` when a set
    /// is waiting for `MODE,SURVEY`); false for sensors 1–2 when they hold nothing to keep
    /// (`board_config::holds_set`): a blob of an idle filter's zeros would load as a set
    /// and, for sensor 1, stop the witness.
    fn read(self, acq: &BoardAcquisition, staged: &Staged, out: &mut [f32; MAX_VALUES]) -> bool {
        let n = self.values();
        match self {
            Slot::Model(s) if s > 0 && !bc::holds_set(acq, staged, s.into()) => return false,
            Slot::Model(s) => out[..n].copy_from_slice(&bc::coefficients(acq, staged, s.into())),
            Slot::FluxCal => out[..n].copy_from_slice(&acq.flux_calibration().to_array()),
            Slot::Lag => out[0] = acq.lag_s(),
            Slot::FluxTemp => out[..n].copy_from_slice(&acq.flux_temp_calibration().to_array()),
        }
        true
    }

    /// Applies stored values (`None`: the slot was absent or invalid). `Err` only for
    /// sensor 0's model, whose absence means "calibrate"; sensors 1–2 without theirs
    /// calibrate on their own. A paper set (16 values) is the board's vector with
    /// `fluxmod` 0.
    fn apply(self, acq: &mut BoardAcquisition, v: Option<&[f32]>) -> Result<(), ()> {
        match self {
            Slot::Model(s) => {
                let Some(v) = v else {
                    return if s == 0 { Err(()) } else { Ok(()) };
                };
                let mut c = [0f32; N_COEF];
                c[..v.len()].copy_from_slice(v);
                let r = bc::load_set(acq, s.into(), &c);
                // sensors 1–2: a bad blob is refused, that sensor calibrates
                if s == 0 { r.map_err(|_| ()) } else { Ok(()) }
            }
            Slot::FluxCal => {
                let cal = v
                    .and_then(|v| v.try_into().ok())
                    .and_then(FluxCalibration::from_array);
                acq.set_flux_calibration(cal.unwrap_or(FluxCalibration::IDENTITY));
                Ok(())
            }
            Slot::Lag => {
                if v.is_none_or(|v| acq.set_lag_s(v[0]).is_err()) {
                    let _ = acq.set_lag_s(0.0);
                }
                Ok(())
            }
            Slot::FluxTemp => {
                // a set saved by a serial-fluxgate image is none here (no temperature)
                let cal = v
                    .filter(|_| FLUX_HAS_TEMPERATURE)
                    .and_then(|v| v.try_into().ok())
                    .and_then(FluxTempCal::from_array);
                acq.set_flux_temp_calibration(cal.unwrap_or(FluxTempCal::NONE));
                Ok(())
            }
        }
    }
}

/// Loads the stored slots, the sets in `form`, into the acquisition. `Err` when the model's blob is missing or invalid (the board then
/// calibrates; the later slots are not read). Bytes past an `MCS2` image's blobs hold no
/// valid blob: sensors 1–2 then calibrate.
pub fn load(raw: &[u8; LEN], form: Form, acq: &mut BoardAcquisition) -> Result<(), ()> {
    let mut at = 0;
    for s in SLOTS {
        let n = s.values_in(form);
        let mut v = [0f32; MAX_VALUES];
        let ok = decode_blob(&raw[at..], s.id(form), &mut v[..n]).is_ok();
        s.apply(acq, ok.then_some(&v[..n]))?;
        at += blob_len(n);
    }
    Ok(())
}

/// Every slot back to its default (what an erased store loads as): no coefficients (the
/// filter, restarted by the caller, calibrates), identity fluxgate calibration, τ = 0, no
/// temperature drift.
pub fn defaults(acq: &mut BoardAcquisition) {
    for s in SLOTS {
        // the model has no default to apply: its `Err` means "calibrate", as after boot
        let _ = s.apply(acq, None);
    }
}

/// Encodes the acquisition's current values as a whole store image.
pub fn save(acq: &BoardAcquisition, staged: &Staged, raw: &mut [u8; LEN]) -> Result<(), ()> {
    let mut at = 0;
    for s in SLOTS {
        let mut v = [0f32; MAX_VALUES];
        let n = s.values();
        if s.read(acq, staged, &mut v) {
            at += encode_blob(s.id(Form::Board), &v[..n], &mut raw[at..]).map_err(|_| ())?;
        } else {
            // absent: erased bytes, which no blob decodes from (that sensor calibrates)
            let end = at + blob_len(n);
            raw.get_mut(at..end).ok_or(())?.fill(0xFF);
            at = end;
        }
    }
    Ok(())
}

/// Images in the store, written alternately.
pub const N_IMAGES: usize = 2;
/// Images at the earlier firmware's place (the real board's sectors 10 and 11): the same
/// two images, read by boot when no current one is valid, retired by `FACTORY,ERASE`.
pub const N_OLD_IMAGES: usize = N_IMAGES;
/// Bytes of one image: magic, sequence number (u32 LE), the blobs, CRC-32 (u32 LE).
pub const IMAGE_LEN: usize = 8 + LEN + 4;
const IMAGE_MAGIC: [u8; 4] = *b"MCS4";

/// The images boot reads: magic, slots held, form of the sets; the CRC follows the slots.
/// `MCS3` and `MCS2` are earlier firmware's (`MCS2` before sensors 1–2), in either form:
/// the paper model's, or its `flux-witness` build's (the current vector).
const LAYOUTS: [([u8; 4], usize, Form); 5] = [
    (IMAGE_MAGIC, SLOTS.len(), Form::Board),
    (*b"MCS3", SLOTS.len(), Form::Paper),
    (*b"MCS3", SLOTS.len(), Form::Board),
    (*b"MCS2", SLOTS_V2, Form::Paper),
    (*b"MCS2", SLOTS_V2, Form::Board),
];

/// One image's bytes.
pub type Image = [u8; IMAGE_LEN];

/// An image that reads as erased flash.
pub const ERASED: Image = [0xFF; IMAGE_LEN];

/// The sequence number of a valid image (magic and CRC check), current or earlier.
pub fn sequence(img: &Image) -> Option<u32> {
    layout(img).map(|(seq, _)| seq)
}

/// A valid image's sequence number and the form of its sets: the first of [`LAYOUTS`]
/// whose magic it has and whose CRC checks where that layout puts it.
fn layout(img: &Image) -> Option<(u32, Form)> {
    let seq = img[4..8].try_into().ok().map(u32::from_le_bytes)?;
    LAYOUTS.iter().find_map(|&(magic, slots, form)| {
        let len = slots_len(slots, form);
        let crc = img[8 + len..12 + len]
            .try_into()
            .ok()
            .map(u32::from_le_bytes)?;
        (img[..4] == magic && crc32(&img[..8 + len]) == crc).then_some((seq, form))
    })
}

/// Which image to load: the valid one with the newest sequence number (compared modulo
/// 2^32, so the counter may wrap), if any.
pub fn newest(seqs: [Option<u32>; N_IMAGES]) -> Option<usize> {
    match seqs {
        [Some(a), Some(b)] => Some(usize::from(b.wrapping_sub(a) as i32 > 0)),
        [Some(_), None] => Some(0),
        [None, Some(_)] => Some(1),
        [None, None] => None,
    }
}

/// Where the next `SAVE` goes and with which sequence number: the image that is not the
/// newest, one past it.
pub fn next(seqs: [Option<u32>; N_IMAGES]) -> (usize, u32) {
    match newest(seqs) {
        Some(i) => (1 - i, seqs[i].unwrap_or(0).wrapping_add(1)),
        None => (0, 1),
    }
}

/// Loads a valid image's blobs (`Err`: no valid model blob: calibrate).
pub fn load_image(img: &Image, acq: &mut BoardAcquisition) -> Result<(), ()> {
    let form = layout(img).map_or(Form::Board, |(_, f)| f);
    load(part(img, 8), form, acq)
}

/// Loads a store written before the two images existed: the blobs alone at the start of
/// the earlier firmware's second image (the real board's sector 11). No CRC says their
/// form: the paper model's (that firmware's), else the current one; a set that is not
/// the paper model's fails at the first blob, before anything is applied.
pub fn load_legacy(img: &Image, acq: &mut BoardAcquisition) -> Result<(), ()> {
    load(part(img, 0), Form::Paper, acq).or_else(|()| load(part(img, 0), Form::Board, acq))
}

/// `LEN` bytes of an image from `at` (always in range: `at` ≤ 8).
fn part(img: &Image, at: usize) -> &[u8; LEN] {
    img.get(at..at + LEN)
        .and_then(|b| b.try_into().ok())
        .unwrap_or(&[0xFF; LEN])
}

/// Seals the acquisition's current values (the model's `staged` ones when given) as image
/// `seq`.
pub fn seal(seq: u32, acq: &BoardAcquisition, staged: &Staged, img: &mut Image) -> Result<(), ()> {
    img[..4].copy_from_slice(&IMAGE_MAGIC);
    img[4..8].copy_from_slice(&seq.to_le_bytes());
    let body: &mut [u8; LEN] = (&mut img[8..8 + LEN]).try_into().map_err(|_| ())?;
    save(acq, staged, body)?;
    let crc = crc32(&img[..8 + LEN]);
    img[8 + LEN..].copy_from_slice(&crc.to_le_bytes());
    Ok(())
}
