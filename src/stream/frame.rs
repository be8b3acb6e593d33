//! Where a laserd program lies on the controller: the work coordinate system
//! (G54) its jobs run in.
//!
//! laserd's programs are in bed coordinates: 0 to the stage's travel on X
//! and Y (`[stage] travel_x`, `travel_y`), 0 at the end of travel toward
//! minus. Machine coordinates depend on the controller:
//! * without homing (`$22=0`) they count from where it was switched on, and
//!   the program runs in them (G54 = 0), as a dry-run assumes;
//! * a homed Grbl's machine space is negative (its soft limits are
//!   −`$130`..0): an axis homing toward plus (the default) has its switch at
//!   0, the far end of its travel, so the bed's 0 is at −travel; one whose
//!   `$23` bit is set has its switch at −`$130`, which is the bed's 0. Grbl
//!   built with HOMING_FORCE_SET_ORIGIN (`Z` in `[OPT:]`) puts the switch at
//!   0 whichever way the axis homes.
//!
//! The sender writes that origin to G54 (`G10 L2 P1`, only when it differs:
//! Grbl keeps it in EEPROM), so programs, the jog to a job's start and a
//! resume all use bed coordinates, and the machine builder's homing
//! settings are all that is needed.

use crate::error::{Error, Result};

/// The machine position of the bed's 0 on X and Y: the G54 origin a job
/// runs in. `settings` is `$$`, `build_codes` the codes of `[OPT:]`, `travel`
/// the config's stage travel (X, Y).
pub fn program_origin(settings: &[(u32, f64)], build_codes: &str, travel: [f64; 2]) -> Result<[f64; 2]> {
    let value = |n: u32| settings.iter().find(|(k, _)| *k == n).map(|(_, v)| *v);
    // Grbl's $22 is 0/1; grblHAL's is a mask whose bit 0 enables homing.
    let homing = value(22).is_some_and(|v| v as u32 & 1 == 1);
    if !homing {
        return Ok([0.0; 2]);
    }
    let homes_toward_minus = |i: u32| value(23).is_some_and(|v| (v as u32 >> i) & 1 == 1);
    let switch_at_zero = build_codes.contains('Z');
    let mut origin = [0.0; 2];
    for (i, o) in (0u32..).zip(origin.iter_mut()) {
        *o = if !homes_toward_minus(i) {
            -travel[i as usize]
        } else if switch_at_zero {
            0.0
        } else {
            let max_travel = value(130 + i).ok_or_else(|| {
                Error::Stream(format!("${} (max travel) is missing from `$$`: cannot place the program on the homed machine", 130 + i))
            })?;
            -max_travel
        };
    }
    Ok(origin)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(homing: f64, dir_mask: f64) -> Vec<(u32, f64)> {
        vec![(22, homing), (23, dir_mask), (130, 290.0), (131, 280.0)]
    }

    #[test]
    fn the_bed_origin_follows_the_homing_settings() {
        let travel = [300.0, 200.0];
        // Not homed: machine coordinates are the program's.
        assert_eq!(program_origin(&settings(0.0, 3.0), "VNM+", travel).unwrap(), [0.0, 0.0]);
        assert_eq!(program_origin(&[], "", travel).unwrap(), [0.0, 0.0]);
        // Homing toward plus: the switch at 0 is the far end of the bed.
        assert_eq!(program_origin(&settings(1.0, 0.0), "VNM+", travel).unwrap(), [-300.0, -200.0]);
        // X toward minus: its switch, at -$130, is the bed's 0.
        assert_eq!(program_origin(&settings(1.0, 1.0), "VNM+", travel).unwrap(), [-290.0, -200.0]);
        // HOMING_FORCE_SET_ORIGIN: the switch is 0 whichever way.
        assert_eq!(program_origin(&settings(1.0, 2.0), "VNMZ+", travel).unwrap(), [-300.0, 0.0]);
        // grblHAL's $22 mask: bit 0 enables homing.
        assert_eq!(program_origin(&settings(5.0, 0.0), "", travel).unwrap(), [-300.0, -200.0]);
        let err = program_origin(&[(22, 1.0), (23, 1.0)], "", travel).unwrap_err().to_string();
        assert!(err.contains("$130"), "{err}");
    }
}
