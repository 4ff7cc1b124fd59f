//! The store's SQL boundary: the values that cross it and the connection either backend
//! (SQLite, PostgreSQL) offers, so that the store's queries are written once.

/// A value bound to or read from SQL.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// NULL.
    Null,
    /// An integer.
    Int(i64),
    /// A double.
    Real(f64),
    /// Text.
    Text(String),
    /// Bytes.
    Blob(Vec<u8>),
}

impl From<i64> for Value {
    fn from(v: i64) -> Self {
        Self::Int(v)
    }
}

impl From<f64> for Value {
    fn from(v: f64) -> Self {
        Self::Real(v)
    }
}

impl From<&str> for Value {
    fn from(v: &str) -> Self {
        Self::Text(v.to_owned())
    }
}

impl From<String> for Value {
    fn from(v: String) -> Self {
        Self::Text(v)
    }
}

impl From<&String> for Value {
    fn from(v: &String) -> Self {
        Self::Text(v.clone())
    }
}

impl From<Vec<u8>> for Value {
    fn from(v: Vec<u8>) -> Self {
        Self::Blob(v)
    }
}

impl<T: Into<Value>> From<Option<T>> for Value {
    fn from(v: Option<T>) -> Self {
        v.map_or(Self::Null, Into::into)
    }
}

/// One result row.
#[derive(Debug, Clone, PartialEq)]
pub struct Row(pub Vec<Value>);

impl Row {
    fn at(&self, i: usize) -> Result<&Value, String> {
        self.0
            .get(i)
            .ok_or_else(|| format!("column {i} of a {}-column row", self.0.len()))
    }

    /// Column `i` as an integer.
    pub fn int(&self, i: usize) -> Result<i64, String> {
        match self.at(i)? {
            Value::Int(v) => Ok(*v),
            other => Err(format!("column {i} is {other:?}, not an integer")),
        }
    }

    /// Column `i` as a double (an integer is widened).
    pub fn real(&self, i: usize) -> Result<f64, String> {
        match self.at(i)? {
            Value::Real(v) => Ok(*v),
            Value::Int(v) => Ok(*v as f64),
            other => Err(format!("column {i} is {other:?}, not a number")),
        }
    }

    /// Column `i` as text.
    pub fn text(&self, i: usize) -> Result<String, String> {
        match self.at(i)? {
            Value::Text(v) => Ok(v.clone()),
            other => Err(format!("column {i} is {other:?}, not text")),
        }
    }

    /// Column `i` as text or NULL.
    pub fn opt_text(&self, i: usize) -> Result<Option<String>, String> {
        match self.at(i)? {
            Value::Null => Ok(None),
            _ => self.text(i).map(Some),
        }
    }

    /// Column `i` as bytes.
    pub fn blob(&self, i: usize) -> Result<Vec<u8>, String> {
        match self.at(i)? {
            Value::Blob(v) => Ok(v.clone()),
            other => Err(format!("column {i} is {other:?}, not bytes")),
        }
    }
}

/// The dialects the store speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dialect {
    /// SQLite (the embedded default).
    Sqlite,
    /// PostgreSQL (the fleet's shared store).
    Postgres,
}

impl Dialect {
    /// The column that orders a session's events as they were written.
    pub fn event_order(self) -> &'static str {
        match self {
            Self::Sqlite => "rowid",
            Self::Postgres => "id",
        }
    }

    /// The database's clock as Unix time in seconds (servers of a fleet compare heartbeats
    /// on one clock, not on their own).
    pub fn now_s(self) -> &'static str {
        match self {
            Self::Sqlite => "((julianday('now') - 2440587.5) * 86400.0)",
            Self::Postgres => "(EXTRACT(EPOCH FROM clock_timestamp())::DOUBLE PRECISION)",
        }
    }
}

/// One connection to a backend. Statements are written with SQLite's `?1`, `?2`… placeholders
/// (the PostgreSQL connection rewrites them); errors come back as text naming the cause.
pub trait Conn: Send {
    /// The rows `sql` returns.
    fn query(&mut self, sql: &str, params: &[Value]) -> Result<Vec<Row>, String>;
    /// Runs `sql`; the number of rows it changed.
    fn execute(&mut self, sql: &str, params: &[Value]) -> Result<u64, String>;
    /// Runs several `;`-separated statements without parameters.
    fn batch(&mut self, sql: &str) -> Result<(), String>;
    /// Whether the connection is gone (a new one is needed).
    fn is_broken(&self) -> bool {
        false
    }
}

/// Runs `body` in one transaction on `conn`: committed if it succeeds, rolled back if not.
pub fn transaction<T>(
    conn: &mut dyn Conn,
    body: impl FnOnce(&mut dyn Conn) -> Result<T, String>,
) -> Result<T, String> {
    conn.batch("BEGIN")?;
    match body(conn) {
        Ok(v) => {
            conn.batch("COMMIT")?;
            Ok(v)
        }
        Err(e) => {
            let _ = conn.batch("ROLLBACK");
            Err(e)
        }
    }
}

/// `VALUES` rows for `rows` rows of `columns` placeholders each, numbered from `?1`:
/// `(?1, ?2), (?3, ?4)`.
pub fn values_list(rows: usize, columns: usize) -> String {
    let mut out = String::with_capacity(rows * columns * 5);
    for r in 0..rows {
        if r > 0 {
            out.push_str(", ");
        }
        out.push('(');
        for c in 0..columns {
            if c > 0 {
                out.push_str(", ");
            }
            out.push_str(&format!("?{}", r * columns + c + 1));
        }
        out.push(')');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_lists_number_their_placeholders_in_order() {
        assert_eq!(values_list(2, 3), "(?1, ?2, ?3), (?4, ?5, ?6)");
        assert_eq!(values_list(1, 1), "(?1)");
    }
}
