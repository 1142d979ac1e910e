//! A small deterministic generator for the randomized unit tests (xorshift64):
//! the same cases on every run, no dependency.

pub struct XorShift(u64);

impl XorShift {
    /// `seed` must not be 0.
    pub fn new(seed: u64) -> Self {
        XorShift(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
}
