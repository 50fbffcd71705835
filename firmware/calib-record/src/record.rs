//! The record codec and the configuration hash.
//!
//! Flash content is untrusted input: [`decode`] checks everything (length, erased
//! state, magic, version, commit mark, CRC, path list, finiteness, alignment, motor
//! constants, configuration) and never panics. Coefficients are not range-checked
//! against the coefficient limit: that limit depends on the health configuration, and
//! `mras::Tracker::set_coefficients` enforces it when the record is applied. Motor
//! constants are checked for sign and finiteness only (plausibility is the
//! identification's business).

use core::f32::consts::PI;

use crc::{Crc, NoTable, CRC_32_ISO_HDLC};
use mras::config::MAX_HARMONIC;
use mras::{Coefficients, Config, Cplx, PathKind, MAX_PATHS};

use crate::layout::{
    COMMIT_MARK, COMMIT_OFFSET, CRC_OFFSET, DOUBLE_WORD_BYTES, ERASED_BYTE, FLAG_REVERSED,
    FORMAT_VERSION, HEADER_BYTES, MAGIC, MOTOR_BYTES, MOTOR_FIELDS, MOTOR_OFFSET, PATH_ENTRY_BYTES,
    RECORD_BYTES, TAG_AMPLITUDE_QUADRATURE, TAG_HARMONIC, TAG_OFFSET,
};

/// Bitwise CRC (no 1 KiB table in flash): the record is checked once per boot.
const CRC32: Crc<u32, NoTable> = Crc::<u32, NoTable>::new(&CRC_32_ISO_HDLC);

/// Electrical zero of the rotor as the sensor sees it: θe = dir·(p/N)·θs + offset_e_rad,
/// with dir = -1 when `reversed`.
///
/// p is the motor's pole-pair count as the alignment sweep measured it (`pole_pairs`),
/// N the sensor's periods per mechanical revolution. The configured N and pole-pair
/// count are covered by [`config_hash`], so an alignment is never applied to another
/// sensor or drive configuration. A record holds only an offset that is finite and
/// within [-π, π] (`core::f32::consts::PI`, both ends included) and a pole-pair count
/// of at least 1.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Alignment {
    pub offset_e_rad: f32,
    /// The sensor angle turns against the motor's phase sequence.
    pub reversed: bool,
    /// The motor's pole pairs the offset belongs to; 0: the drive's configured count
    /// (an alignment not measured yet, never stored).
    pub pole_pairs: u16,
}

impl Alignment {
    /// No offset, same direction, the configured pole pairs.
    pub const IDENTITY: Self = Self {
        offset_e_rad: 0.0,
        reversed: false,
        pole_pairs: 0,
    };

    /// The pole pairs this alignment is for: its own count, or `configured` where it
    /// carries none (0, not measured yet).
    pub const fn pole_pairs_or(&self, configured: u16) -> u16 {
        if self.pole_pairs == 0 {
            configured
        } else {
            self.pole_pairs
        }
    }
}

/// The motor's constants identified at commissioning (what the drive runs on).
///
/// A record holds only finite values, with `r_ohm`, `ld_h`, `lq_h`, `flux_wb` and
/// `inertia_kg_m2` > 0, `v_inverter_v` ≥ 0, and `viscous_nm_s_rad` and `coulomb_nm` of
/// any sign ([`RecordError::BadMotor`] otherwise). The two friction terms are a
/// least-squares fit at one speed region, where viscous and constant friction are
/// separated only weakly: either may come out negative while their sum is right. Stored
/// bit for bit, in declaration order ([`crate::layout`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotorConstants {
    /// Phase (stator) resistance (Ω).
    pub r_ohm: f32,
    /// d-axis inductance (H).
    pub ld_h: f32,
    /// q-axis inductance (H).
    pub lq_h: f32,
    /// The inverter's voltage error (dead time and device drops) along the identification's axis (V).
    pub v_inverter_v: f32,
    /// Permanent-magnet flux linkage (Wb).
    pub flux_wb: f32,
    /// Rotor (and load) inertia (kg·m²).
    pub inertia_kg_m2: f32,
    /// Viscous friction (N·m·s/rad).
    pub viscous_nm_s_rad: f32,
    /// The constant friction torque (N·m): Coulomb's at the commissioning's sign of speed, or a constant load.
    pub coulomb_nm: f32,
}

impl MotorConstants {
    /// The fields in record order.
    const fn to_fields(self) -> [f32; MOTOR_FIELDS] {
        [
            self.r_ohm,
            self.ld_h,
            self.lq_h,
            self.v_inverter_v,
            self.flux_wb,
            self.inertia_kg_m2,
            self.viscous_nm_s_rad,
            self.coulomb_nm,
        ]
    }

    /// Inverse of [`MotorConstants::to_fields`].
    const fn from_fields(f: [f32; MOTOR_FIELDS]) -> Self {
        let [r_ohm, ld_h, lq_h, v_inverter_v, flux_wb, inertia_kg_m2, viscous_nm_s_rad, coulomb_nm] =
            f;
        Self {
            r_ohm,
            ld_h,
            lq_h,
            v_inverter_v,
            flux_wb,
            inertia_kg_m2,
            viscous_nm_s_rad,
            coulomb_nm,
        }
    }

    /// All finite; the resistance, inductances, flux and inertia > 0; the inverter's
    /// voltage error ≥ 0 (`-0.0` included); the viscous and the constant friction of
    /// any sign.
    fn is_valid(&self) -> bool {
        // Both comparisons are false for NaN; `is_finite` excludes +∞.
        let positive = |v: f32| v.is_finite() && v > 0.0;
        let non_negative = |v: f32| v.is_finite() && v >= 0.0;
        [
            self.r_ohm,
            self.ld_h,
            self.lq_h,
            self.flux_wb,
            self.inertia_kg_m2,
        ]
        .into_iter()
        .all(positive)
            && non_negative(self.v_inverter_v)
            && [self.viscous_nm_s_rad, self.coulomb_nm]
                .into_iter()
                .all(f32::is_finite)
    }
}

/// What a record persists.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Calibration {
    pub coefficients: Coefficients,
    pub alignment: Alignment,
    pub motor: MotorConstants,
}

/// A decoded, fully validated record.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Record {
    pub calibration: Calibration,
    /// Store counter; the newer of two records wins (serial-number arithmetic).
    pub sequence: u32,
    /// [`config_hash`] of the configuration (and motor) that produced the calibration.
    pub config_hash: u32,
}

/// Why bytes are not a usable record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RecordError {
    /// Fewer than [`RECORD_BYTES`] bytes.
    Truncated,
    /// Every byte is 0xFF: nothing was ever written (or the slot was just erased).
    Erased,
    /// Not a calibration record (or a partial erase).
    BadMagic,
    /// Written by another format version (`expected` is [`FORMAT_VERSION`]); its layout
    /// cannot be trusted, so nothing else is read.
    UnsupportedVersion { found: u16, expected: u16 },
    /// The last double word is still erased: a write was interrupted.
    Incomplete,
    /// CRC or commit mark wrong: corrupted bits or a torn write.
    BadCrc,
    /// Path count above `MAX_PATHS`, unknown kind tag, a kind the core refuses, or two
    /// paths nulling the same error harmonic.
    BadPathList,
    /// A coefficient is NaN or infinite.
    NonFiniteValue,
    /// The alignment offset is not finite or outside [-π, π], a direction flag other
    /// than bit 0 is set, or the pole-pair count is 0.
    BadAlignment,
    /// A motor constant is not finite, the resistance, an inductance, the flux linkage
    /// or the inertia is not > 0, or the inverter's voltage error is < 0 (the friction
    /// terms may have any sign).
    BadMotor,
    /// Intact, but produced under another configuration (sensor periods, pole pairs,
    /// input scaling or path list differ).
    ConfigMismatch { stored: u32, expected: u32 },
}

impl RecordError {
    /// The variant's name, without its fields: stable, for logs (`defmt`, a console)
    /// that should not depend on `Debug` formatting.
    pub const fn name(&self) -> &'static str {
        match self {
            RecordError::Truncated => "Truncated",
            RecordError::Erased => "Erased",
            RecordError::BadMagic => "BadMagic",
            RecordError::UnsupportedVersion { .. } => "UnsupportedVersion",
            RecordError::Incomplete => "Incomplete",
            RecordError::BadCrc => "BadCrc",
            RecordError::BadPathList => "BadPathList",
            RecordError::NonFiniteValue => "NonFiniteValue",
            RecordError::BadAlignment => "BadAlignment",
            RecordError::BadMotor => "BadMotor",
            RecordError::ConfigMismatch { .. } => "ConfigMismatch",
        }
    }
}

/// The front end's scaling of raw samples into the core's units,
/// `x = (x_raw - offset_x) · gain_x`: the coefficients are in those units, so a
/// calibration means nothing under another scaling.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InputScaling {
    pub offset_x: f32,
    pub offset_y: f32,
    pub gain_x: f32,
    pub gain_y: f32,
}

impl InputScaling {
    /// Samples already in the core's units.
    pub const IDENTITY: Self = Self {
        offset_x: 0.0,
        offset_y: 0.0,
        gain_x: 1.0,
        gain_y: 1.0,
    };
}

/// Hash of the configuration fields that give a [`Calibration`] its meaning.
///
/// Covered: `sensor_periods` and the motor's `pole_pairs` (the alignment maps the
/// sensor angle to the electrical angle through p/N: for another sensor or motor it
/// means nothing), the front end's input scaling and the path list (count, kinds,
/// order). Not covered: sample period, observer, adaptation law, gates, health and
/// convergence settings: retuning those must not throw away a calibration.
///
/// CRC-32/ISO-HDLC over, little-endian: `sensor_periods` (u16); `pole_pairs` (u16);
/// `offset_x`, `offset_y`, `gain_x`, `gain_y` (f32 bits, `-0.0` as `0.0`); path count
/// (u8); per path its (tag, h) bytes as in the record; then, for a bank from the data
/// (`paths_from_data`), one byte 1. Changing this requires a new [`FORMAT_VERSION`].
pub fn config_hash(cfg: &Config, pole_pairs: u16, input: &InputScaling) -> u32 {
    let mut d = CRC32.digest();
    d.update(&cfg.sensor_periods.to_le_bytes());
    d.update(&pole_pairs.to_le_bytes());
    let i = input;
    for v in [i.offset_x, i.offset_y, i.gain_x, i.gain_y] {
        d.update(&canonical_bits(v).to_le_bytes());
    }
    let paths = cfg.paths();
    // `paths()` holds at most MAX_PATHS (16) entries.
    d.update(&[paths.len() as u8]);
    for &k in paths {
        d.update(&kind_bytes(k));
    }
    // A bank from the data: the paths above are its first stage, the record's list says
    // what the survey added. One byte more, so that fixed banks keep their hashes.
    if cfg.paths_from_data {
        d.update(&[1]);
    }
    d.finalize()
}

fn canonical_bits(v: f32) -> u32 {
    if v == 0.0 {
        0
    } else if v.is_nan() {
        f32::NAN.to_bits()
    } else {
        v.to_bits()
    }
}

/// Tag and h byte of a path kind.
fn kind_bytes(k: PathKind) -> [u8; 2] {
    match k {
        PathKind::Offset => [TAG_OFFSET, 0],
        PathKind::AmplitudeQuadrature => [TAG_AMPLITUDE_QUADRATURE, 0],
        PathKind::Harmonic(h) => [TAG_HARMONIC, h as u8],
    }
}

/// Inverse of [`kind_bytes`], accepting only kinds the core accepts (non-canonical
/// encodings such as an offset with h ≠ 0 are refused).
fn kind_from_bytes(tag: u8, h: u8) -> Option<PathKind> {
    match (tag, h) {
        (TAG_OFFSET, 0) => Some(PathKind::Offset),
        (TAG_AMPLITUDE_QUADRATURE, 0) => Some(PathKind::AmplitudeQuadrature),
        (TAG_HARMONIC, h) => {
            let h = h as i8;
            // Same rule as `mras::Config::validate`.
            let valid = !(0..=3).contains(&h) && h.unsigned_abs() <= MAX_HARMONIC.unsigned_abs();
            valid.then_some(PathKind::Harmonic(h))
        }
        _ => None,
    }
}

/// Encode a record into `buf`; returns the number of bytes to program ([`RECORD_BYTES`]).
///
/// Does not validate: a calibration with non-finite values, an invalid path list, an
/// out-of-range alignment offset or invalid motor constants encodes, and [`decode`]
/// refuses it ([`crate::store`] checks before erasing anything). The offset and the
/// motor constants are stored bit for bit (`-0.0` stays `-0.0`).
pub fn encode(
    calibration: &Calibration,
    seq: u32,
    cfg_hash: u32,
    buf: &mut [u8; RECORD_BYTES],
) -> usize {
    let coefs = &calibration.coefficients;
    let alignment = &calibration.alignment;
    buf.fill(0);
    let mut w = Writer { rest: &mut buf[..] };
    w.put(MAGIC.to_le_bytes());
    w.put(FORMAT_VERSION.to_le_bytes());
    let flags = if alignment.reversed { FLAG_REVERSED } else { 0 };
    // `Coefficients` holds at most MAX_PATHS (16) paths.
    w.put([coefs.len() as u8, flags]);
    w.put(seq.to_le_bytes());
    w.put(cfg_hash.to_le_bytes());
    w.put(alignment.offset_e_rad.to_bits().to_le_bytes());
    w.put(alignment.pole_pairs.to_le_bytes());
    w.put([0u8; 2]);
    for (kind, v) in coefs.iter() {
        let [tag, h] = kind_bytes(kind);
        w.put([tag, h, 0, 0]);
        w.put(v.re.to_bits().to_le_bytes());
        w.put(v.im.to_bits().to_le_bytes());
    }
    // At a fixed offset whatever the path count; it fills the bytes up to the CRC.
    if let Some(block) = buf.get_mut(MOTOR_OFFSET..CRC_OFFSET) {
        let mut w = Writer { rest: block };
        for v in calibration.motor.to_fields() {
            w.put(v.to_bits().to_le_bytes());
        }
    }
    let crc = crc_of(buf);
    if let Some(commit) = buf.get_mut(COMMIT_OFFSET..RECORD_BYTES) {
        let mut w = Writer { rest: commit };
        w.put(crc.to_le_bytes());
        w.put(COMMIT_MARK.to_le_bytes());
    }
    RECORD_BYTES
}

/// Decode and validate a record read from flash (`bytes` may be longer, e.g. a page).
///
/// Checks, in order: length, erased, magic, version (it fixes the layout), commit
/// double word programmed, CRC and commit mark, path list, finite values, alignment,
/// motor constants, and last the configuration hash.
pub fn decode(bytes: &[u8], expected_hash: u32) -> Result<Record, RecordError> {
    let rec = decode_intact(bytes)?;
    if rec.config_hash != expected_hash {
        return Err(RecordError::ConfigMismatch {
            stored: rec.config_hash,
            expected: expected_hash,
        });
    }
    Ok(rec)
}

/// Everything [`decode`] checks except the configuration hash.
pub(crate) fn decode_intact(bytes: &[u8]) -> Result<Record, RecordError> {
    let rec = bytes.get(..RECORD_BYTES).ok_or(RecordError::Truncated)?;
    if rec.iter().all(|&b| b == ERASED_BYTE) {
        return Err(RecordError::Erased);
    }
    let mut r = Reader { rest: rec };
    if r.u32()? != MAGIC {
        return Err(RecordError::BadMagic);
    }
    // The version decides the layout, so it is checked before the CRC location is trusted.
    let version = r.u16()?;
    if version != FORMAT_VERSION {
        return Err(RecordError::UnsupportedVersion {
            found: version,
            expected: FORMAT_VERSION,
        });
    }
    let commit = rec
        .get(COMMIT_OFFSET..RECORD_BYTES)
        .ok_or(RecordError::Truncated)?;
    if commit.iter().all(|&b| b == ERASED_BYTE) {
        return Err(RecordError::Incomplete);
    }
    let mut c = Reader { rest: commit };
    if c.u32()? != crc_of(rec) || c.u32()? != COMMIT_MARK {
        return Err(RecordError::BadCrc);
    }

    let count = usize::from(r.u8()?);
    let flags = r.u8()?;
    let sequence = r.u32()?;
    let config_hash = r.u32()?;
    let offset_e_rad = f32::from_bits(r.u32()?);
    let pole_pairs = r.u16()?;
    let _reserved = r.take::<2>()?;
    if count > MAX_PATHS {
        return Err(RecordError::BadPathList);
    }
    let mut kinds = [PathKind::Offset; MAX_PATHS];
    let mut values = [Cplx::ZERO; MAX_PATHS];
    for (kind, value) in kinds.iter_mut().zip(values.iter_mut()).take(count) {
        let [tag, h, _, _] = r.take::<4>()?;
        *kind = kind_from_bytes(tag, h).ok_or(RecordError::BadPathList)?;
        *value = Cplx::new(f32::from_bits(r.u32()?), f32::from_bits(r.u32()?));
    }
    let kinds = kinds.get(..count).ok_or(RecordError::BadPathList)?;
    let values = values.get(..count).ok_or(RecordError::BadPathList)?;
    // Same rule as `mras::Config::validate`: one path per error harmonic.
    for (n, k) in kinds.iter().enumerate() {
        let earlier = kinds.get(..n).unwrap_or_default();
        if earlier
            .iter()
            .any(|e| e.error_harmonic() == k.error_harmonic())
        {
            return Err(RecordError::BadPathList);
        }
    }
    if values
        .iter()
        .any(|v| !(v.re.is_finite() && v.im.is_finite()))
    {
        return Err(RecordError::NonFiniteValue);
    }
    let mut coefficients = Coefficients::zeros(kinds);
    for (&k, &v) in kinds.iter().zip(values) {
        // Kinds are distinct (distinct error harmonics), so every `set` finds its path.
        if !coefficients.set(k, v) {
            return Err(RecordError::BadPathList);
        }
    }
    // Bits 1-7 have no meaning in this version: refuse rather than ignore them.
    let reversed = match flags {
        0 => false,
        FLAG_REVERSED => true,
        _ => return Err(RecordError::BadAlignment),
    };
    // `contains` is false for NaN and for ±∞ (outside the range).
    if !(-PI..=PI).contains(&offset_e_rad) || pole_pairs == 0 {
        return Err(RecordError::BadAlignment);
    }
    let mut m = Reader {
        rest: rec
            .get(MOTOR_OFFSET..CRC_OFFSET)
            .ok_or(RecordError::Truncated)?,
    };
    let mut fields = [0.0f32; MOTOR_FIELDS];
    for f in &mut fields {
        *f = f32::from_bits(m.u32()?);
    }
    let motor = MotorConstants::from_fields(fields);
    if !motor.is_valid() {
        return Err(RecordError::BadMotor);
    }
    Ok(Record {
        calibration: Calibration {
            coefficients,
            alignment: Alignment {
                offset_e_rad,
                reversed,
                pole_pairs,
            },
            motor,
        },
        sequence,
        config_hash,
    })
}

fn crc_of(record: &[u8]) -> u32 {
    CRC32.checksum(record.get(..CRC_OFFSET).unwrap_or(record))
}

/// Panic-free little-endian cursor over untrusted bytes.
struct Reader<'a> {
    rest: &'a [u8],
}

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> Result<[u8; N], RecordError> {
        let (head, tail) = self
            .rest
            .split_first_chunk::<N>()
            .ok_or(RecordError::Truncated)?;
        self.rest = tail;
        Ok(*head)
    }

    fn u8(&mut self) -> Result<u8, RecordError> {
        self.take::<1>().map(|[b]| b)
    }

    fn u16(&mut self) -> Result<u16, RecordError> {
        self.take().map(u16::from_le_bytes)
    }

    fn u32(&mut self) -> Result<u32, RecordError> {
        self.take().map(u32::from_le_bytes)
    }
}

/// Cursor for [`encode`]; the layout constants guarantee the record fits, and a write
/// past the end is dropped rather than panicking.
struct Writer<'a> {
    rest: &'a mut [u8],
}

impl Writer<'_> {
    fn put<const N: usize>(&mut self, bytes: [u8; N]) {
        if let Some((head, tail)) = core::mem::take(&mut self.rest).split_first_chunk_mut::<N>() {
            *head = bytes;
            self.rest = tail;
        }
    }
}

// The field sizes written above (4+2+1+1+4+4+4+4, 4+4+4, 8·4, 4+4) match the layout.
const _: () = assert!(
    HEADER_BYTES == 24
        && PATH_ENTRY_BYTES == 12
        && MOTOR_BYTES == MOTOR_FIELDS * 4
        && DOUBLE_WORD_BYTES == 8
);
