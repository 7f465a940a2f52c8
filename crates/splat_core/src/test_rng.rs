//! The unit tests' random numbers: a 64-bit LCG (Knuth's MMIX constants), so test data
//! never depends on a crate's stream.

pub(crate) struct Lcg(u64);

impl Lcg {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    fn step(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        self.0
    }

    /// Uniform in [0, 1), 24 bits.
    pub fn uniform(&mut self) -> f32 {
        (self.step() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform 31-bit integer.
    pub fn u31(&mut self) -> u32 {
        (self.step() >> 33) as u32
    }
}
