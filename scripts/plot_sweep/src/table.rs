//! The CSV tables the plot binaries read: a header row naming the columns, then data rows of
//! as many comma-separated fields (blank lines skipped). Errors name the file, the data row
//! (counted from 1 after the header) and the column.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};

/// A CSV read whole, its columns by name.
pub struct Table {
    path: PathBuf,
    columns: HashMap<String, usize>,
    /// The data rows' fields, trimmed; each row has the header's length.
    pub rows: Vec<Vec<String>>,
}

impl Table {
    /// Reads `path`; refuses an empty file, rows whose length differs from the header's, and a
    /// table without data rows.
    pub fn read(path: &Path) -> Result<Table> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let split =
            |l: &str| -> Vec<String> { l.split(',').map(|f| f.trim().to_string()).collect() };
        let mut lines = text.lines().filter(|l| !l.trim().is_empty());
        let header = split(
            lines
                .next()
                .ok_or_else(|| anyhow!("{}: empty", path.display()))?,
        );
        let mut rows = Vec::new();
        for (k, line) in lines.enumerate() {
            let f = split(line);
            if f.len() != header.len() {
                bail!(
                    "{}: data row {} has {} fields, the header {}",
                    path.display(),
                    k + 1,
                    f.len(),
                    header.len()
                );
            }
            rows.push(f);
        }
        if rows.is_empty() {
            bail!("{}: no data rows", path.display());
        }
        let columns = header
            .into_iter()
            .enumerate()
            .map(|(i, h)| (h, i))
            .collect();
        Ok(Table {
            path: path.to_path_buf(),
            columns,
            rows,
        })
    }

    /// The field of column `name` in data row `row` (0-based).
    pub fn get(&self, row: usize, name: &str) -> Result<&str> {
        let i = *self
            .columns
            .get(name)
            .ok_or_else(|| anyhow!("{}: no column {name}", self.path.display()))?;
        Ok(&self.rows[row][i])
    }

    /// The finite number in column `name` of data row `row`.
    pub fn num(&self, row: usize, name: &str) -> Result<f64> {
        let text = self.get(row, name)?;
        let v: f64 = text.parse().with_context(|| {
            format!(
                "{}: data row {}, column {name}: '{text}' is not a number",
                self.path.display(),
                row + 1
            )
        })?;
        if !v.is_finite() {
            bail!(
                "{}: data row {}, column {name} is not finite",
                self.path.display(),
                row + 1
            );
        }
        Ok(v)
    }

    /// [`Table::num`], or NaN where the field is empty.
    pub fn optional(&self, row: usize, name: &str) -> Result<f64> {
        if self.get(row, name)?.is_empty() {
            Ok(f64::NAN)
        } else {
            self.num(row, name)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Writes `text` to `name` in `dir`.
    fn write(dir: &mlt_test_support::TempDir, name: &str, text: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn fields_by_name_and_errors_that_name_file_row_and_column() {
        let d = mlt_test_support::TempDir::new("plot-table");
        let write = |name: &str, text: &str| write(&d, name, text);
        let t = Table::read(&write("ok.csv", "a, b,c\n\n1,x, \n2.5,y,3\n")).unwrap();
        assert_eq!(t.rows.len(), 2);
        assert_eq!(t.get(0, "b").unwrap(), "x");
        assert_eq!(t.num(1, "a").unwrap(), 2.5);
        assert!(t.optional(0, "c").unwrap().is_nan());
        assert_eq!(t.optional(1, "c").unwrap(), 3.0);
        let e = format!("{:#}", t.num(0, "b").unwrap_err());
        assert!(
            e.contains("ok.csv") && e.contains("data row 1") && e.contains("column b"),
            "{e}"
        );
        assert!(t
            .get(0, "zz")
            .unwrap_err()
            .to_string()
            .contains("no column zz"));
        let e = Table::read(&write("short.csv", "a,b\n1\n"))
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("data row 1 has 1 fields, the header 2"), "{e}");
        assert!(Table::read(&write("empty.csv", "\n")).is_err());
        assert!(Table::read(&write("header.csv", "a,b\n")).is_err());
        let e = format!(
            "{:#}",
            Table::read(&write("inf.csv", "a\ninf\n"))
                .unwrap()
                .num(0, "a")
                .unwrap_err()
        );
        assert!(e.contains("not finite"), "{e}");
    }
}
