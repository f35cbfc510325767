//! What the bootloader did this boot, left for the application in 32 bytes of RAM that neither links
//! (`docs/update.md`): six little-endian words, the last the complement of the first, so that a report from an
//! earlier boot's garbage is told from a real one only by chance of 2⁻⁶⁴.

/// `BootReport::to_words()[0]`.
pub const MAGIC: u32 = 0xB007_2E90;
/// Words in the report.
pub const WORDS: usize = 6;

/// What the bootloader did.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BootAction {
    /// Booted ACTIVE as it was.
    Booted,
    /// Swapped in the image from DFU (a trial boot: it must confirm itself).
    Swapped,
    /// Swapped the previous image back (the trial image never confirmed).
    Reverted,
    /// Refused the image in DFU ([`BootReport::refusal`]) and booted ACTIVE as it was.
    Refused,
}

impl BootAction {
    const fn code(self) -> u32 {
        match self {
            Self::Booted => 0,
            Self::Swapped => 1,
            Self::Reverted => 2,
            Self::Refused => 3,
        }
    }
}

/// The report.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BootReport {
    /// What happened.
    pub action: BootAction,
    /// Why the DFU image was refused: [`crate::update::ImageError::code`], 0 if it was not.
    pub refusal: u8,
    /// The version in ACTIVE's header after the boot (0: no valid header, e.g. flashed with a probe).
    pub active_version: u32,
    /// The version in DFU's header as this boot found it, before any swap (0: none): the image swapped in, refused,
    /// or (after a revert) reverted.
    pub dfu_version: u32,
}

impl BootReport {
    /// The report as the bootloader writes it.
    pub const fn to_words(&self) -> [u32; WORDS] {
        [
            MAGIC,
            self.action.code(),
            self.refusal as u32,
            self.active_version,
            self.dfu_version,
            !MAGIC,
        ]
    }

    /// The report in `words`, if they hold one (magic, check word, known action).
    pub const fn from_words(words: &[u32; WORDS]) -> Option<Self> {
        if words[0] != MAGIC || words[5] != !MAGIC || words[2] > 0xFF {
            return None;
        }
        let action = match words[1] {
            0 => BootAction::Booted,
            1 => BootAction::Swapped,
            2 => BootAction::Reverted,
            3 => BootAction::Refused,
            _ => return None,
        };
        Some(Self {
            action,
            refusal: words[2] as u8,
            active_version: words[3],
            dfu_version: words[4],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_garbage() {
        let r = BootReport {
            action: BootAction::Refused,
            refusal: 6,
            active_version: 7,
            dfu_version: 9,
        };
        let w = r.to_words();
        assert_eq!(w, [0xB007_2E90, 3, 6, 7, 9, 0x4FF8_D16F]);
        assert_eq!(BootReport::from_words(&w), Some(r));
        let mut bad = w;
        bad[5] ^= 1;
        assert_eq!(BootReport::from_words(&bad), None);
        let mut bad = w;
        bad[1] = 4;
        assert_eq!(BootReport::from_words(&bad), None);
        assert_eq!(BootReport::from_words(&[0; WORDS]), None);
    }
}
