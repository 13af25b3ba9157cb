//! Forward-mode dual numbers over θ for the covariance recursion's terms.

/// A number with its gradient over θ (forward-mode differentiation of the
/// covariance-recursion terms; exact to rounding). `N = 4` carries the
/// gradient; `N = 0` only the value (the same operations on it, so the
/// value is the same to the bit), for passes that do not need `∂P/∂θ`.
#[derive(Debug, Clone, Copy)]
pub(super) struct Dual<const N: usize> {
    pub(super) v: f64,
    pub(super) d: [f64; N],
}

impl<const N: usize> Dual<N> {
    pub(super) fn cst(v: f64) -> Self {
        Dual { v, d: [0.0; N] }
    }
    pub(super) fn var(v: f64, i: usize) -> Self {
        let mut d = [0.0; N];
        if let Some(x) = d.get_mut(i) {
            *x = 1.0;
        }
        Dual { v, d }
    }
    pub(super) fn sin_cos(self) -> (Self, Self) {
        let (s, c) = self.v.sin_cos();
        (Dual { v: s, d: self.d.map(|x| c * x) }, Dual { v: c, d: self.d.map(|x| -s * x) })
    }
}

impl<const N: usize> std::ops::Add for Dual<N> {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Dual { v: self.v + o.v, d: std::array::from_fn(|i| self.d[i] + o.d[i]) }
    }
}
impl<const N: usize> std::ops::Sub for Dual<N> {
    type Output = Self;
    fn sub(self, o: Self) -> Self {
        Dual { v: self.v - o.v, d: std::array::from_fn(|i| self.d[i] - o.d[i]) }
    }
}
impl<const N: usize> std::ops::Mul for Dual<N> {
    type Output = Self;
    // The product rule adds.
    #[allow(clippy::suspicious_arithmetic_impl)]
    fn mul(self, o: Self) -> Self {
        Dual { v: self.v * o.v, d: std::array::from_fn(|i| self.d[i] * o.v + self.v * o.d[i]) }
    }
}
impl<const N: usize> std::ops::Mul<f64> for Dual<N> {
    type Output = Self;
    fn mul(self, o: f64) -> Self {
        Dual { v: self.v * o, d: self.d.map(|x| x * o) }
    }
}
impl<const N: usize> std::ops::Div for Dual<N> {
    type Output = Self;
    fn div(self, o: Self) -> Self {
        let inv = 1.0 / o.v;
        let q = self.v * inv;
        Dual { v: q, d: std::array::from_fn(|i| (self.d[i] - q * o.d[i]) * inv) }
    }
}
impl<const N: usize> std::ops::Neg for Dual<N> {
    type Output = Self;
    fn neg(self) -> Self {
        Dual { v: -self.v, d: self.d.map(|x| -x) }
    }
}
