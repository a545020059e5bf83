//! Where each quantity sits in the HMD vector ([`super::HMD_DIM`] entries), for every reader and writer
//! of it (the observation model, its noise, translation and the renderer).

/// Tracked devices: the headset, the left wrist, the right wrist.
pub const DEVICES: usize = 3;
/// Entries per device: its rotation `R` (9, row-major), then its position `t` (3).
pub const BLOCK: usize = 12;

/// First entry of device `d`'s block (its rotation, row-major).
pub const fn device(d: usize) -> usize {
    BLOCK * d
}

/// First entry of device `d`'s position.
pub const fn position(d: usize) -> usize {
    BLOCK * d + 9
}

/// First entry of hand tip `k` (0 left, 1 right; 3 entries each).
pub const fn tip(k: usize) -> usize {
    BLOCK * DEVICES + 3 * k
}

/// The device that carries hand tip `k` (its wrist).
pub const fn tip_device(k: usize) -> usize {
    k + 1
}
