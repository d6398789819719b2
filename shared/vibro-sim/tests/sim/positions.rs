//! The ten-positions campaign (MODEL.md section 9) as `vibrocomp identify positions`
//! reads it: the CSV has exactly the reader's columns, and the paper's closed form
//! (22) applied to the simulated positions gives the VE components that follow from
//! the AL-15 passport, including the one place where the exact asymmetry term departs
//! from the model (21).

use crate::common::*;
use std::f64::consts::FRAC_2_PI;
use vibro_ident::{closed_form, Amplitudes, TestPosition};
use vibro_sim::campaign::POSITION_COLUMNS;
use vibro_sim::{run_campaign, write_positions_csv, write_summary_csv, CampaignOptions};

#[test]
fn ten_positions_csv_identifies_the_passport_components() {
    // 2 s vibrating: 20 batches of 0.1 s, 3 cycles of 30 Hz each.
    let s = shortened_campaign("ten-positions", 0.5, 2.0);
    let out = run_campaign(&s, &CampaignOptions { threads: 2 }, &mut |_| {}).unwrap();
    assert_eq!(out.len(), 10);
    let mut csv_bytes = Vec::new();
    write_positions_csv(&mut csv_bytes, &out, &["ten positions, test".to_string()]).unwrap();
    let text = String::from_utf8(csv_bytes).unwrap();
    assert!(text.starts_with("# ten positions, test\n"));
    let mut reader = csv::ReaderBuilder::new()
        .comment(Some(b'#'))
        .from_reader(text.as_bytes());
    let header: Vec<String> = reader.headers().unwrap().iter().map(String::from).collect();
    assert_eq!(header, POSITION_COLUMNS);
    // Read back as the identification reads it.
    let positions: Vec<TestPosition> = reader
        .records()
        .map(|r| {
            let r = r.unwrap();
            let v = |i: usize| r[i].parse::<f64>().unwrap();
            TestPosition {
                tp: r[0].parse().unwrap(),
                angle_deg: v(1),
                amplitudes: Amplitudes {
                    a_b3_g: v(2),
                    a_b1_g: v(3),
                    a_b2_g: v(4),
                },
                du_v: v(6) - v(5),
                du_sigma_v: Some(v(7)),
            }
        })
        .collect();
    let p = vibro_config::resolve_passport("AL-15").unwrap();
    let cf = closed_form(&positions, p.k1_v_per_g).unwrap().components;
    // The components from the passport, written out ([P1 (15)-(16)], aB = 0.42 g).
    let ab: f64 = 0.42;
    let k = p.k;
    let asym_g = 0.5 * p.k1 * p.d1a * FRAC_2_PI * ab; // exact E|aB sin| term at g3 = 0
    let want = [
        (
            "d0(1)",
            cf.d01_g,
            asym_g + 0.5 * k[2] * ab.powi(2) + 0.375 * k[4] * ab.powi(4),
        ),
        ("d0(2)", cf.d02_g, 0.5 * p.m31_per_g * ab * ab),
        ("d0(3)", cf.d03_g, 0.5 * p.m32_per_g * ab * ab),
        (
            "delta(1)",
            cf.delta1,
            1.5 * k[3] * ab.powi(2) + 1.875 * k[5] * ab.powi(4),
        ),
        // (21) takes d0(1) as the same in every position; the exact asymmetry term
        // vanishes where |g3| >= aB (TP1, 2, 4, 5, 6, 8), so (22) moves 1.5 times it
        // from d0(1) into delta(2) (MODEL.md section 6; docs/identification.md).
        (
            "delta(2)",
            cf.delta2_per_g,
            3.0 * k[4] * ab.powi(2) - 1.5 * asym_g,
        ),
        ("delta(3)", cf.delta3_per_g2, 5.0 * k[5] * ab.powi(2)),
    ];
    for (name, got, expected) in want {
        println!("{name:<9} closed form {got:+.6e}   passport {expected:+.6e}");
        assert!(
            (got - expected).abs() < 1e-11,
            "{name}: {got} vs {expected}"
        );
    }
    // The summary CSV has one row per condition with the model lab's columns.
    let mut summary = Vec::new();
    write_summary_csv(&mut summary, &out).unwrap();
    let mut reader = csv::Reader::from_reader(summary.as_slice());
    let header: Vec<String> = reader.headers().unwrap().iter().map(String::from).collect();
    for col in [
        "condition_id",
        "angle_deg",
        "aL1_g",
        "aL2_g",
        "aL3_g",
        "direction",
        "measured_ve_g",
        "measured_ve_sigma_g",
        "exact_ve_g",
        "published_ve_g",
        "drift_check",
    ] {
        assert!(header.iter().any(|h| h == col), "{col}");
    }
    let rows: Vec<csv::StringRecord> = reader.records().map(|r| r.unwrap()).collect();
    assert_eq!(rows.len(), 10);
    let col = |name: &str| header.iter().position(|h| h == name).unwrap();
    assert_eq!(&rows[8][col("direction")], "ia-oa-45");
    assert_eq!(&rows[8][col("aB1_g")], "0.42");
    assert_eq!(&rows[4][col("aL3_g")], "-1");
    assert_eq!(&rows[0][col("drift_check")], "accepted");
    let measured: f64 = rows[2][col("measured_ve_g")].parse().unwrap();
    assert!((measured - cf.d01_g).abs() < 1e-12, "TP3 measures d0(1)");
}
