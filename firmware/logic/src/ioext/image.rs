//! The extension's persisted settings and their byte image.
//!
//! The settings are what a master configures and a box needs after a power
//! cut to work without one: the enable bit, the configuration, the transmit
//! data (the outputs' state at power-up) and the mapping. The status bit,
//! the receive data and the counters are not persisted.
//!
//! Image ([`IMAGE_LEN`] bytes, little-endian), validated as a whole on
//! decode like the PoStep60 settings image:
//!
//! | offset | bytes | field |
//! |---|---|---|
//! | 0 | 1 | format, [`IMAGE_FORMAT`] |
//! | 1 | 4 | I/O options (only bit 0 may be set) |
//! | 5 | 4 | configuration (only writable bits, bit 28 set, status 0) |
//! | 9 | 32 | transmit data, words 0..15 |
//! | 41 | 1 | debounce K (1..=255) |
//! | 42 | 112 | per axis 0..7: BIN1, BIN2, end switch, run, moving, fault, idle — 7 entry registers (u16) |

use super::config::{cfg, options, Config, WireBits, WORDS};
use super::mapping::{
    input_from_register, input_register, output_from_register, output_register, AxisMap, Mapping,
    MAX_AXES,
};

/// Image format written by this firmware.
pub const IMAGE_FORMAT: u8 = 1;
const ENTRIES: usize = 7;
/// Bytes of an image.
pub const IMAGE_LEN: usize = 42 + MAX_AXES * ENTRIES * 2;

/// Why an image was not accepted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ImageError {
    /// Another image format (written by other firmware).
    Format(u8),
    /// Wrong length or a field out of range.
    Invalid,
}

/// What the extension persists.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct IoSettings {
    /// I/O options bit 0.
    pub enabled: bool,
    pub config: Config,
    pub tx: WireBits,
    pub mapping: Mapping,
}

impl IoSettings {
    /// Factory: disabled, [`Config::FACTORY`], zero data, nothing mapped.
    pub const FACTORY: IoSettings = IoSettings {
        enabled: false,
        config: Config::FACTORY,
        tx: WireBits::ZERO,
        mapping: Mapping::FACTORY,
    };

    pub fn encode(&self, out: &mut [u8; IMAGE_LEN]) {
        let mut at = 0usize;
        let mut put = |b: &[u8]| {
            if let Some(dst) = at.checked_add(b.len()).and_then(|end| out.get_mut(at..end)) {
                dst.copy_from_slice(b);
            }
            at = at.saturating_add(b.len());
        };
        put(&[IMAGE_FORMAT]);
        put(&u32::from(self.enabled).to_le_bytes());
        put(&self.config.register(false).to_le_bytes());
        for w in self.tx.words() {
            put(&w.to_le_bytes());
        }
        put(&[self.mapping.debounce]);
        for a in &self.mapping.axes {
            for i in a.inputs {
                put(&input_register(i).to_le_bytes());
            }
            for o in a.outputs {
                put(&output_register(o).to_le_bytes());
            }
        }
    }

    pub fn decode(image: &[u8]) -> Result<IoSettings, ImageError> {
        let (&format, _) = image.split_first().ok_or(ImageError::Invalid)?;
        if format != IMAGE_FORMAT {
            return Err(ImageError::Format(format));
        }
        if image.len() != IMAGE_LEN {
            return Err(ImageError::Invalid);
        }
        let mut r = Reader {
            input: image,
            at: 1,
        };
        let opts = r.u32()?;
        if opts & !options::WRITABLE != 0 {
            return Err(ImageError::Invalid);
        }
        let raw = r.u32()?;
        if raw & !cfg::WRITABLE != 0 {
            return Err(ImageError::Invalid);
        }
        let config = match Config::from_register(raw) {
            Ok((c, false)) => c,
            _ => return Err(ImageError::Invalid),
        };
        let mut words = [0u16; WORDS];
        for w in words.iter_mut() {
            *w = r.u16()?;
        }
        let debounce = r.u8()?;
        if debounce == 0 {
            return Err(ImageError::Invalid);
        }
        let mut axes = [AxisMap::NONE; MAX_AXES];
        for a in axes.iter_mut() {
            for i in a.inputs.iter_mut() {
                *i = input_from_register(r.u16()?).map_err(|_| ImageError::Invalid)?;
            }
            for o in a.outputs.iter_mut() {
                *o = output_from_register(r.u16()?).map_err(|_| ImageError::Invalid)?;
            }
        }
        Ok(IoSettings {
            enabled: opts & options::ENABLE != 0,
            config,
            tx: WireBits::from_words(words),
            mapping: Mapping { debounce, axes },
        })
    }
}

struct Reader<'a> {
    input: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> Result<[u8; N], ImageError> {
        let end = self.at.checked_add(N).ok_or(ImageError::Invalid)?;
        let s = self.input.get(self.at..end).ok_or(ImageError::Invalid)?;
        self.at = end;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }
    fn u8(&mut self) -> Result<u8, ImageError> {
        Ok(u8::from_le_bytes(self.take()?))
    }
    fn u16(&mut self) -> Result<u16, ImageError> {
        Ok(u16::from_le_bytes(self.take()?))
    }
    fn u32(&mut self) -> Result<u32, ImageError> {
        Ok(u32::from_le_bytes(self.take()?))
    }
}

#[cfg(test)]
mod tests {
    #![allow(
        clippy::indexing_slicing,
        clippy::arithmetic_side_effects,
        clippy::unwrap_used
    )]
    #![allow(clippy::panic)]
    use super::super::config::SpiMode;
    use super::super::mapping::{Input, InputBit, Output, OutputBit};
    use super::*;

    #[test]
    fn factory_image_round_trips() {
        let mut img = [0u8; IMAGE_LEN];
        IoSettings::FACTORY.encode(&mut img);
        assert_eq!(IMAGE_LEN, 154);
        assert_eq!(IoSettings::decode(&img), Ok(IoSettings::FACTORY));
    }

    #[test]
    fn every_field_survives_the_image() {
        let mut s = IoSettings {
            enabled: true,
            config: Config::new(33, SpiMode::MODE3, 255)
                .unwrap()
                .with_auto_restart(true)
                .with_cs_hold(true),
            tx: WireBits::from_words(core::array::from_fn(|k| 0x1111 * k as u16)),
            mapping: Mapping::FACTORY,
        };
        s.mapping.debounce = 255;
        for (k, a) in s.mapping.axes.iter_mut().enumerate() {
            for (j, i) in Input::ALL.into_iter().enumerate() {
                a.set_input(
                    i,
                    Some(InputBit {
                        bit: (k * 10 + j) as u8,
                        nc: j % 2 == 1,
                    }),
                );
            }
            a.set_output(
                Output::Fault,
                Some(OutputBit {
                    bit: 255,
                    inverted: true,
                }),
            );
        }
        let mut img = [0u8; IMAGE_LEN];
        s.encode(&mut img);
        assert_eq!(IoSettings::decode(&img), Ok(s));
        // Little-endian fields at their offsets.
        assert_eq!(img[1..5], [1, 0, 0, 0]);
        assert_eq!(
            u32::from_le_bytes(img[5..9].try_into().unwrap()),
            s.config.register(false)
        );
        assert_eq!(img[9..13], [0, 0, 0x11, 0x11]);
        assert_eq!(img[41], 255);
        assert_eq!(img[42..44], [0x00, 0x80]);
    }

    #[test]
    fn other_formats_and_out_of_range_fields_are_rejected() {
        let mut img = [0u8; IMAGE_LEN];
        IoSettings::FACTORY.encode(&mut img);
        let bad = |f: &dyn Fn(&mut [u8; IMAGE_LEN])| {
            let mut i = img;
            f(&mut i);
            IoSettings::decode(&i)
        };
        assert_eq!(bad(&|i| i[0] = 2), Err(ImageError::Format(2)));
        assert_eq!(bad(&|i| i[1] = 2), Err(ImageError::Invalid)); // options bit 1
        assert_eq!(bad(&|i| i[8] &= !0x10), Err(ImageError::Invalid)); // SLI
        assert_eq!(bad(&|i| i[6] |= 0x08), Err(ImageError::Invalid)); // status bit 11
        assert_eq!(bad(&|i| i[6] |= 0x01), Err(ImageError::Invalid)); // bit 8
        assert_eq!(bad(&|i| i[41] = 0), Err(ImageError::Invalid)); // debounce 0
        assert_eq!(bad(&|i| i[42] = 1), Err(ImageError::Invalid)); // unmapped with a bit
        assert_eq!(
            IoSettings::decode(&img[..IMAGE_LEN - 1]),
            Err(ImageError::Invalid)
        );
        assert_eq!(IoSettings::decode(&[]), Err(ImageError::Invalid));
        let mut long = [0u8; IMAGE_LEN + 1];
        long[..IMAGE_LEN].copy_from_slice(&img);
        assert_eq!(IoSettings::decode(&long), Err(ImageError::Invalid));
    }

    #[test]
    fn random_images_never_panic() {
        let mut x = 0x9E37_79B9_u32;
        let mut img = [0u8; IMAGE_LEN];
        for round in 0..3000 {
            for b in img.iter_mut() {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                *b = x as u8;
            }
            img[0] = IMAGE_FORMAT;
            let _ = IoSettings::decode(&img[..round % (IMAGE_LEN + 1)]);
            let _ = IoSettings::decode(&img);
        }
    }
}
