//! The results table as Parquet, written with Parquet's own low-level writer (no
//! Arrow): one row group, plain encoding, no compression, so that pandas, polars,
//! DuckDB and pyarrow read it as they are.

use parquet::data_type::{ByteArray, ByteArrayType, DoubleType, Int64Type};
use parquet::file::properties::WriterProperties;
use parquet::file::writer::SerializedFileWriter;
use std::sync::Arc;

use crate::Row;

/// The table's columns in order, with their Parquet types (docs/archive.md, "The
/// table"). Optional ones are null where they do not apply.
pub const COLUMNS: &[(&str, &str)] = &[
    ("job", "REQUIRED BYTE_ARRAY"),
    ("kind", "REQUIRED BYTE_ARRAY"),
    ("log", "OPTIONAL BYTE_ARRAY"),
    ("unit", "OPTIONAL BYTE_ARRAY"),
    ("model", "OPTIONAL BYTE_ARRAY"),
    ("stage", "OPTIONAL BYTE_ARRAY"),
    ("window_s", "OPTIONAL DOUBLE"),
    ("windows", "OPTIONAL INT64"),
    ("error_g", "OPTIONAL DOUBLE"),
    ("verdict", "OPTIONAL BYTE_ARRAY"),
    ("effect", "OPTIONAL BYTE_ARRAY"),
    ("param", "OPTIONAL BYTE_ARRAY"),
    ("value", "OPTIONAL DOUBLE"),
    ("sigma", "OPTIONAL DOUBLE"),
    ("problem", "OPTIONAL BYTE_ARRAY"),
    ("elapsed_s", "REQUIRED DOUBLE"),
    ("worker", "REQUIRED BYTE_ARRAY"),
];

fn schema_text() -> String {
    let mut s = String::from("message vibrocomp_archive {\n");
    for (name, ty) in COLUMNS {
        let annotation = if ty.ends_with("BYTE_ARRAY") {
            " (UTF8)"
        } else {
            ""
        };
        s.push_str(&format!("  {ty} {name}{annotation};\n"));
    }
    s.push('}');
    s
}

enum Column {
    Text(Vec<Option<String>>),
    Double(Vec<Option<f64>>),
    Int(Vec<Option<i64>>),
}

fn columns(rows: &[(Row, f64, String)]) -> Vec<Column> {
    let text = |f: &dyn Fn(&Row) -> Option<String>| {
        Column::Text(rows.iter().map(|(r, _, _)| f(r)).collect())
    };
    let double = |f: &dyn Fn(&Row) -> Option<f64>| {
        Column::Double(rows.iter().map(|(r, _, _)| f(r)).collect())
    };
    vec![
        text(&|r| Some(r.job.clone())),
        text(&|r| Some(r.kind.clone())),
        text(&|r| r.log.clone()),
        text(&|r| r.unit.clone()),
        text(&|r| r.model.clone()),
        text(&|r| r.stage.clone()),
        double(&|r| r.window_s),
        Column::Int(rows.iter().map(|(r, _, _)| r.windows).collect()),
        double(&|r| r.error_g),
        text(&|r| r.verdict.clone()),
        text(&|r| r.effect.clone()),
        text(&|r| r.param.clone()),
        double(&|r| r.value),
        double(&|r| r.sigma),
        text(&|r| r.problem.clone()),
        Column::Double(rows.iter().map(|(_, e, _)| Some(*e)).collect()),
        Column::Text(rows.iter().map(|(_, _, w)| Some(w.clone())).collect()),
    ]
}

/// Definition levels (1: a value, 0: null) and the values present.
fn split<T: Clone>(column: &[Option<T>]) -> (Vec<i16>, Vec<T>) {
    let levels = column.iter().map(|v| i16::from(v.is_some())).collect();
    let values = column.iter().flatten().cloned().collect();
    (levels, values)
}

/// The rows (each with its job's `elapsed_s` and `worker`) as a Parquet file.
pub fn parquet_bytes(rows: &[(Row, f64, String)]) -> Result<Vec<u8>, String> {
    let schema = Arc::new(
        parquet::schema::parser::parse_message_type(&schema_text()).map_err(|e| e.to_string())?,
    );
    let props = Arc::new(WriterProperties::builder().build());
    let mut writer =
        SerializedFileWriter::new(Vec::new(), schema, props).map_err(|e| e.to_string())?;
    let mut group = writer.next_row_group().map_err(|e| e.to_string())?;
    for ((_, ty), column) in COLUMNS.iter().zip(columns(rows)) {
        let required = ty.starts_with("REQUIRED");
        let Some(mut cw) = group.next_column().map_err(|e| e.to_string())? else {
            return Err("the schema has fewer columns than the table".into());
        };
        let written = match column {
            Column::Text(v) => {
                let (levels, values) = split(&v);
                let values: Vec<ByteArray> = values
                    .into_iter()
                    .map(|s| ByteArray::from(s.into_bytes()))
                    .collect();
                let levels = (!required).then_some(levels.as_slice());
                cw.typed::<ByteArrayType>()
                    .write_batch(&values, levels, None)
            }
            Column::Double(v) => {
                let (levels, values) = split(&v);
                let levels = (!required).then_some(levels.as_slice());
                cw.typed::<DoubleType>().write_batch(&values, levels, None)
            }
            Column::Int(v) => {
                let (levels, values) = split(&v);
                let levels = (!required).then_some(levels.as_slice());
                cw.typed::<Int64Type>().write_batch(&values, levels, None)
            }
        };
        written.map_err(|e| e.to_string())?;
        cw.close().map_err(|e| e.to_string())?;
    }
    group.close().map_err(|e| e.to_string())?;
    writer.into_inner().map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_is_a_parquet_file_with_its_columns_and_nulls() {
        let rows = vec![
            (
                Row {
                    job: "compensate/0/m".into(),
                    kind: "compensate".into(),
                    error_g: Some(1e-3),
                    windows: Some(12),
                    ..Row::default()
                },
                0.5,
                "h/1".into(),
            ),
            (
                Row {
                    job: "lab/U".into(),
                    kind: "lab".into(),
                    problem: Some("bad".into()),
                    ..Row::default()
                },
                0.25,
                "h/2".into(),
            ),
        ];
        let bytes = parquet_bytes(&rows).unwrap();
        assert_eq!(&bytes[..4], b"PAR1");
        assert_eq!(&bytes[bytes.len() - 4..], b"PAR1");
        use parquet::file::reader::{FileReader, SerializedFileReader};
        let dir = tempfile::TempDir::new().unwrap();
        let path = dir.path().join("t.parquet");
        std::fs::write(&path, &bytes).unwrap();
        let reader = SerializedFileReader::new(std::fs::File::open(&path).unwrap()).unwrap();
        let meta = reader.metadata();
        assert_eq!(meta.file_metadata().num_rows(), 2);
        let names: Vec<&str> = meta
            .file_metadata()
            .schema_descr()
            .columns()
            .iter()
            .map(|c| c.name())
            .collect();
        let expected: Vec<&str> = COLUMNS.iter().map(|c| c.0).collect();
        assert_eq!(names, expected);
        let mut seen = Vec::new();
        for row in reader.get_row_iter(None).unwrap() {
            seen.push(row.unwrap().to_string());
        }
        assert!(
            seen[0].contains("error_g: 0.001") && seen[0].contains("problem: null"),
            "{seen:?}"
        );
        assert!(
            seen[1].contains("problem: \"bad\"") && seen[1].contains("windows: null"),
            "{seen:?}"
        );
        // No row, still a table with its columns.
        assert_eq!(&parquet_bytes(&[]).unwrap()[..4], b"PAR1");
    }
}
