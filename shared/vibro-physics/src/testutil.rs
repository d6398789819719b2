//! Passports of MODEL.md sections 5 and 7, written out in the tests' own code (not read
//! from `config/`), so tests check the shipped files and the formulas independently.

#![allow(dead_code)] // each helper is used by some of the test modules

use crate::passport::{Passport, PassportSpec};

pub(crate) fn al15_spec() -> PassportSpec {
    PassportSpec {
        id: "AL-15".into(),
        a0_g: 3.324e-3,
        k1: 1.0,
        k1_v_per_g: -1.6698,
        d1a_ppm: 15.0,
        k2_ppm_per_g: 105.0,
        k3_ppm_per_g2: 87.0,
        k4_ppm_per_g3: 10.0,
        k5_ppm_per_g4: 0.9,
        m1_ppm: 1150.0,
        m2_ppm: 1150.0,
        m31_ppm_per_g: 11.6,
        m32_ppm_per_g: 11.6,
        lambda: vec![],
    }
}

pub(crate) fn al15() -> Passport {
    Passport::try_from_spec(&al15_spec()).unwrap()
}

/// [P2 Table 4]; cross-axis terms as AL-15.
pub(crate) fn al1m() -> Passport {
    Passport::try_from_spec(&PassportSpec {
        id: "AL-1M".into(),
        a0_g: 1.2e-3,
        d1a_ppm: 25.0,
        ..al15_spec()
    })
    .unwrap()
}

/// [P2 Table 4]; no cross-axis terms published.
pub(crate) fn aks05() -> Passport {
    Passport::try_from_spec(&PassportSpec {
        id: "AKS-05".into(),
        a0_g: 0.5e-3,
        k1: 1.0,
        k1_v_per_g: 1.0,
        d1a_ppm: 15.0,
        k2_ppm_per_g: 2.0,
        k3_ppm_per_g2: 7.0,
        k4_ppm_per_g3: 0.02,
        k5_ppm_per_g4: 0.3,
        m1_ppm: 0.0,
        m2_ppm: 0.0,
        m31_ppm_per_g: 0.0,
        m32_ppm_per_g: 0.0,
        lambda: vec![],
    })
    .unwrap()
}
