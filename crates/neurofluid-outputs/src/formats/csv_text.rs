//! CSV text through the `csv` crate (quoting and escaping are its job): one place for every
//! CSV the trainer writes (metrics, per-frame evaluation, sweep tables).

/// The CSV text of `records` (each a row of cells), one line per record, `\n`-terminated.
pub fn csv_text<I, R>(records: I) -> String
where
    I: IntoIterator<Item = R>,
    R: IntoIterator,
    R::Item: AsRef<[u8]>,
{
    let mut w = csv::WriterBuilder::new()
        .terminator(csv::Terminator::Any(b'\n'))
        .flexible(true)
        .from_writer(Vec::new());
    for r in records {
        w.write_record(r)
            .expect("writing CSV to memory cannot fail");
    }
    let bytes = w.into_inner().expect("flushing CSV to memory cannot fail");
    String::from_utf8(bytes).expect("CSV of UTF-8 cells is UTF-8")
}

/// A number's cell; empty for a missing value.
pub fn cell(v: Option<f64>) -> String {
    v.map(|x| x.to_string()).unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_that_need_quotes_get_them() {
        let text = csv_text([
            vec!["a".to_string(), "b,c".into(), "say \"hi\"".into()],
            vec!["1".into(), cell(None), cell(Some(0.5))],
        ]);
        assert_eq!(text, "a,\"b,c\",\"say \"\"hi\"\"\"\n1,,0.5\n");
    }
}
