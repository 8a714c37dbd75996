//! LPIPS (AlexNet).
