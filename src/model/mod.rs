//! Pure maths.
