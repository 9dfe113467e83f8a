//! The sender slot of each link as stored: 16 bits where every stored sender slot fits in
//! them, else 32 ([`Slots`]), and the [`Slot`] trait the sums read either width through.

/// The sender slot of each link: 16 bits where every stored sender slot fits in them (2 of a
/// link's 20 bytes instead of 4 of 22: the products are bound by reading the links), else 32.
#[derive(Clone, Debug, PartialEq)]
pub(super) enum Slots {
    Narrow(Vec<u16>),
    Wide(Vec<u32>),
}

impl Default for Slots {
    fn default() -> Slots {
        Slots::Narrow(Vec::new())
    }
}

impl Slots {
    /// `slots` in 16 bits each where all fit, else as they are.
    pub(super) fn new(slots: Vec<u32>) -> Slots {
        match slots.iter().map(|&s| u16::try_from(s)).collect() {
            Ok(narrow) => Slots::Narrow(narrow),
            Err(_) => Slots::Wide(slots),
        }
    }

    /// Bytes per slot.
    fn width(&self) -> usize {
        match self {
            Slots::Narrow(_) => 2,
            Slots::Wide(_) => 4,
        }
    }

    /// Heap bytes held.
    pub(super) fn bytes(&self) -> usize {
        let len = match self {
            Slots::Narrow(s) => s.len(),
            Slots::Wide(s) => s.len(),
        };
        self.width() * len
    }
}

/// A sender slot as stored ([`Slots`]).
pub(super) trait Slot: Copy {
    fn index(self) -> usize;
}

impl Slot for u16 {
    #[inline(always)]
    fn index(self) -> usize {
        self as usize
    }
}

impl Slot for u32 {
    #[inline(always)]
    fn index(self) -> usize {
        self as usize
    }
}
