//! A restricted reader of Python's pickle format (protocols 2–5), for data files such as GMR's
//! motions: it builds values and never calls anything. A global (`numpy.dtype`, …) stays a name,
//! a `REDUCE` or `NEWOBJ` stays a call with its arguments, and a `BUILD` attaches the state to the
//! object it builds; [`ndarray`] then reads NumPy's arrays and scalars out of those.
//!
//! Why not a library: `serde-pickle` (the maintained one) replaces every global it does not know
//! by `None`, so a NumPy array's data is gone; `repugnant-pickle` 0.0.1 keeps them but is a
//! one-release scraper. This reader is bounded instead: the file's size, the values it may build
//! (a memo reference copies a value, and a few hundred bytes could otherwise unfold into
//! gigabytes) and their nesting.

use std::collections::HashMap;

/// A value of a pickle.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// `None`.
    None,
    /// `True`/`False`.
    Bool(bool),
    /// An integer that fits 64 bits.
    Int(i64),
    /// A float.
    Float(f64),
    /// A string.
    Str(String),
    /// Bytes.
    Bytes(Vec<u8>),
    /// A list.
    List(Vec<Value>),
    /// A tuple.
    Tuple(Vec<Value>),
    /// A dict, in insertion order.
    Dict(Vec<(Value, Value)>),
    /// A global by module and name (a class or function, never imported).
    Global {
        /// Its module.
        module: String,
        /// Its name.
        name: String,
    },
    /// `callable(*args)` with the state a `BUILD` gave it, kept as data.
    Call {
        /// What would be called.
        callable: Box<Value>,
        /// Its arguments (a tuple).
        args: Box<Value>,
        /// The state set by `BUILD`.
        state: Option<Box<Value>>,
        /// The object's identity, so that a `BUILD` reaches the copies the memo holds.
        id: u32,
    },
}

impl Value {
    /// The string, if this is one.
    pub fn as_str(&self) -> Option<&str> {
        match self {
            Self::Str(s) => Some(s),
            _ => None,
        }
    }

    /// The value of `key` in a dict with string keys.
    pub fn get(&self, key: &str) -> Option<&Value> {
        match self {
            Self::Dict(items) => items
                .iter()
                .find(|(k, _)| k.as_str() == Some(key))
                .map(|(_, v)| v),
            _ => None,
        }
    }

    /// A short name of the kind, for errors.
    pub fn kind(&self) -> String {
        match self {
            Self::None => "None".into(),
            Self::Bool(_) => "a bool".into(),
            Self::Int(_) => "an int".into(),
            Self::Float(_) => "a float".into(),
            Self::Str(_) => "a string".into(),
            Self::Bytes(_) => "bytes".into(),
            Self::List(_) => "a list".into(),
            Self::Tuple(_) => "a tuple".into(),
            Self::Dict(_) => "a dict".into(),
            Self::Global { module, name } => format!("{module}.{name}"),
            Self::Call { callable, .. } => format!("a {} object", callable.kind()),
        }
    }

    /// Values it holds, itself included (what copying it costs).
    fn size(&self) -> usize {
        1 + match self {
            Self::Str(s) => s.len() / 64,
            Self::Bytes(b) => b.len() / 64,
            Self::List(v) | Self::Tuple(v) => v.iter().map(Self::size).sum(),
            Self::Dict(v) => v.iter().map(|(k, x)| k.size() + x.size()).sum(),
            Self::Call {
                callable,
                args,
                state,
                ..
            } => callable.size() + args.size() + state.as_ref().map_or(0, |s| s.size()),
            _ => 0,
        }
    }

    /// How deeply it nests.
    fn depth(&self) -> usize {
        1 + match self {
            Self::List(v) | Self::Tuple(v) => v.iter().map(Self::depth).max().unwrap_or(0),
            Self::Dict(v) => v.iter().map(|(k, x)| k.depth().max(x.depth())).max().unwrap_or(0),
            Self::Call {
                callable,
                args,
                state,
                ..
            } => callable
                .depth()
                .max(args.depth())
                .max(state.as_ref().map_or(0, |s| s.depth())),
            _ => 0,
        }
    }
}

/// A pickle that cannot be read: where in the stream, and what.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("byte {at}: {message}")]
pub struct PickleError {
    /// Offset of the opcode.
    pub at: usize,
    /// What is wrong.
    pub message: String,
}

/// Largest pickle read, bytes.
pub const MAX_PICKLE_BYTES: usize = 512 << 20;
/// Most values the stream may build, memo copies included (each 64 bytes of data counts one).
pub const MAX_VALUES: usize = 5_000_000;
/// Deepest nesting of containers.
pub const MAX_DEPTH: usize = 64;

/// Reads the one value the pickle `data` holds.
pub fn read(data: &[u8]) -> Result<Value, PickleError> {
    if data.len() > MAX_PICKLE_BYTES {
        return Err(PickleError {
            at: 0,
            message: format!("{} bytes; at most {MAX_PICKLE_BYTES}", data.len()),
        });
    }
    Machine {
        data,
        at: 0,
        stack: Vec::new(),
        marks: Vec::new(),
        memo: HashMap::new(),
        built: 0,
        next_id: 0,
    }
    .run()
}

struct Machine<'a> {
    data: &'a [u8],
    at: usize,
    stack: Vec<Value>,
    marks: Vec<usize>,
    memo: HashMap<u32, Value>,
    built: usize,
    next_id: u32,
}

impl Machine<'_> {
    fn run(mut self) -> Result<Value, PickleError> {
        loop {
            let op_at = self.at;
            let op = self.take(1)?[0];
            let fail = |message: String| PickleError { at: op_at, message };
            match op {
                b'.' => {
                    return match (self.stack.pop(), self.stack.is_empty()) {
                        (Some(v), true) => Ok(v),
                        _ => Err(fail("STOP with not exactly one value on the stack".into())),
                    };
                }
                0x80 => {
                    let proto = self.take(1)?[0];
                    if !(2..=5).contains(&proto) {
                        return Err(fail(format!("protocol {proto}; this reader takes 2 to 5")));
                    }
                }
                0x95 => {
                    self.take(8)?;
                }
                b'(' => self.marks.push(self.stack.len()),
                b'}' => self.push(Value::Dict(Vec::new()))?,
                b']' => self.push(Value::List(Vec::new()))?,
                b')' => self.push(Value::Tuple(Vec::new()))?,
                b'N' => self.push(Value::None)?,
                0x88 => self.push(Value::Bool(true))?,
                0x89 => self.push(Value::Bool(false))?,
                b'J' => {
                    let v = i32::from_le_bytes(self.array()?);
                    self.push(Value::Int(v.into()))?;
                }
                b'K' => {
                    let v = self.take(1)?[0];
                    self.push(Value::Int(v.into()))?;
                }
                b'M' => {
                    let v = u16::from_le_bytes(self.array()?);
                    self.push(Value::Int(v.into()))?;
                }
                0x8a => {
                    let n = usize::from(self.take(1)?[0]);
                    let bytes = self.take(n)?;
                    if n > 8 {
                        return Err(fail(format!("an integer of {n} bytes; at most 8")));
                    }
                    let mut v: i64 = 0;
                    for (i, b) in bytes.iter().enumerate() {
                        v |= i64::from(*b) << (8 * i);
                    }
                    if n > 0 && n < 8 && bytes[n - 1] & 0x80 != 0 {
                        v -= 1i64 << (8 * n);
                    }
                    self.push(Value::Int(v))?;
                }
                b'G' => {
                    let v = f64::from_be_bytes(self.array()?);
                    self.push(Value::Float(v))?;
                }
                0x8c | b'X' | 0x8d => {
                    let n = self.length(op)?;
                    let s = std::str::from_utf8(self.take(n)?)
                        .map_err(|_| fail("a string that is not UTF-8".into()))?
                        .to_owned();
                    self.push(Value::Str(s))?;
                }
                b'C' | b'B' | 0x8e | 0x96 | b'U' | b'T' => {
                    let n = self.length(op)?;
                    let b = self.take(n)?.to_vec();
                    self.push(Value::Bytes(b))?;
                }
                b'c' => {
                    let module = self.line()?;
                    let name = self.line()?;
                    self.push(Value::Global { module, name })?;
                }
                0x93 => {
                    let name = self.pop(op_at)?;
                    let module = self.pop(op_at)?;
                    match (module, name) {
                        (Value::Str(module), Value::Str(name)) => {
                            self.push(Value::Global { module, name })?;
                        }
                        _ => return Err(fail("STACK_GLOBAL needs two strings".into())),
                    }
                }
                b'R' | 0x81 => {
                    let args = self.pop(op_at)?;
                    let callable = self.pop(op_at)?;
                    if !matches!(args, Value::Tuple(_)) {
                        return Err(fail(format!("call arguments are {}, not a tuple", args.kind())));
                    }
                    let v = latin1_bytes(&callable, &args).unwrap_or_else(|| {
                        self.next_id += 1;
                        Value::Call {
                            callable: Box::new(callable),
                            args: Box::new(args),
                            state: None,
                            id: self.next_id,
                        }
                    });
                    self.push(v)?;
                }
                b'b' => {
                    let state = self.pop(op_at)?;
                    let Some(Value::Call { state: slot, id, .. }) = self.stack.last_mut() else {
                        return Err(fail("BUILD on something that is not an object".into()));
                    };
                    *slot = Some(Box::new(state.clone()));
                    let id = *id;
                    // The memo holds copies: the object built there too.
                    for v in self.memo.values_mut() {
                        if let Value::Call {
                            state: s, id: other, ..
                        } = v
                            && *other == id
                        {
                            *s = Some(Box::new(state.clone()));
                        }
                    }
                }
                b't' | b'l' | b'd' => {
                    let items = self.pop_mark(op_at)?;
                    let v = match op {
                        b't' => Value::Tuple(items),
                        b'l' => Value::List(items),
                        _ => Value::Dict(pairs(items).map_err(fail)?),
                    };
                    self.push(v)?;
                }
                0x85..=0x87 => {
                    let n = usize::from(op - 0x84);
                    if self.stack.len() < n {
                        return Err(fail("a tuple of more values than the stack holds".into()));
                    }
                    let items = self.stack.split_off(self.stack.len() - n);
                    self.push(Value::Tuple(items))?;
                }
                b's' | b'u' | b'a' | b'e' => {
                    let items = match op {
                        b's' => {
                            let v = self.pop(op_at)?;
                            let k = self.pop(op_at)?;
                            vec![k, v]
                        }
                        b'a' => vec![self.pop(op_at)?],
                        _ => self.pop_mark(op_at)?,
                    };
                    match (self.stack.last_mut(), op) {
                        (Some(Value::Dict(d)), b's' | b'u') => d.extend(pairs(items).map_err(fail)?),
                        (Some(Value::List(l)), b'a' | b'e') => l.extend(items),
                        (other, _) => {
                            return Err(fail(format!(
                                "adding items to {}",
                                other.map_or("nothing".into(), |o| o.kind())
                            )));
                        }
                    }
                    let top = self.stack.last().map_or(0, Value::depth);
                    if top > MAX_DEPTH {
                        return Err(fail(format!("values nest deeper than {MAX_DEPTH}")));
                    }
                }
                0x94 | b'q' | b'r' | b'p' => {
                    let key = match op {
                        0x94 => u32::try_from(self.memo.len()).unwrap_or(u32::MAX),
                        b'q' => self.take(1)?[0].into(),
                        b'r' => u32::from_le_bytes(self.array()?),
                        _ => self
                            .line()?
                            .parse()
                            .map_err(|_| fail("PUT of no number".into()))?,
                    };
                    let top = self
                        .stack
                        .last()
                        .ok_or_else(|| fail("MEMOIZE with an empty stack".into()))?;
                    let copy = top.clone();
                    self.memo.insert(key, copy);
                }
                b'h' | b'j' | b'g' => {
                    let key = match op {
                        b'h' => self.take(1)?[0].into(),
                        b'j' => u32::from_le_bytes(self.array()?),
                        _ => self
                            .line()?
                            .parse()
                            .map_err(|_| fail("GET of no number".into()))?,
                    };
                    let v = self
                        .memo
                        .get(&key)
                        .ok_or_else(|| fail(format!("memo {key} was never set")))?;
                    let v = v.clone();
                    self.push(v)?;
                }
                b'0' => {
                    self.pop(op_at)?;
                }
                b'1' => {
                    self.pop_mark(op_at)?;
                }
                b'2' => {
                    let v = self
                        .stack
                        .last()
                        .ok_or_else(|| fail("DUP with an empty stack".into()))?
                        .clone();
                    self.push(v)?;
                }
                other => {
                    return Err(fail(format!(
                        "opcode 0x{other:02x} is not one a data file needs (no code is run)"
                    )));
                }
            }
        }
    }

    fn take(&mut self, n: usize) -> Result<&[u8], PickleError> {
        let end = self
            .at
            .checked_add(n)
            .filter(|&e| e <= self.data.len())
            .ok_or(PickleError {
                at: self.at,
                message: format!("the file ends inside an opcode ({n} more bytes wanted)"),
            })?;
        let s = &self.data[self.at..end];
        self.at = end;
        Ok(s)
    }

    fn array<const N: usize>(&mut self) -> Result<[u8; N], PickleError> {
        let s = self.take(N)?;
        Ok(std::array::from_fn(|i| s[i]))
    }

    /// The length prefix of a string or bytes opcode.
    fn length(&mut self, op: u8) -> Result<usize, PickleError> {
        let at = self.at;
        let n = match op {
            0x8c | b'C' | b'U' => u64::from(self.take(1)?[0]),
            b'X' | b'B' | b'T' => u64::from(u32::from_le_bytes(self.array()?)),
            _ => u64::from_le_bytes(self.array()?),
        };
        usize::try_from(n)
            .ok()
            .filter(|&n| n <= self.data.len() - self.at)
            .ok_or(PickleError {
                at,
                message: format!("the file ends inside a value said to be {n} bytes long"),
            })
    }

    fn line(&mut self) -> Result<String, PickleError> {
        let rest = &self.data[self.at..];
        let n = rest.iter().position(|&b| b == b'\n').ok_or(PickleError {
            at: self.at,
            message: "a line that never ends".into(),
        })?;
        let s = String::from_utf8_lossy(&rest[..n]).into_owned();
        self.at += n + 1;
        Ok(s)
    }

    fn push(&mut self, v: Value) -> Result<(), PickleError> {
        self.built += v.size();
        if self.built > MAX_VALUES {
            return Err(PickleError {
                at: self.at,
                message: format!("unfolds into more than {MAX_VALUES} values"),
            });
        }
        if v.depth() > MAX_DEPTH {
            return Err(PickleError {
                at: self.at,
                message: format!("values nest deeper than {MAX_DEPTH}"),
            });
        }
        self.stack.push(v);
        Ok(())
    }

    fn pop(&mut self, at: usize) -> Result<Value, PickleError> {
        if self.marks.last().is_some_and(|&m| m >= self.stack.len()) {
            return Err(PickleError {
                at,
                message: "an opcode takes a value from below a MARK".into(),
            });
        }
        self.stack.pop().ok_or(PickleError {
            at,
            message: "an opcode takes a value from an empty stack".into(),
        })
    }

    fn pop_mark(&mut self, at: usize) -> Result<Vec<Value>, PickleError> {
        let m = self.marks.pop().ok_or(PickleError {
            at,
            message: "no MARK before this opcode".into(),
        })?;
        Ok(self.stack.split_off(m.min(self.stack.len())))
    }
}

/// Key-value pairs from a flat list.
fn pairs(items: Vec<Value>) -> Result<Vec<(Value, Value)>, String> {
    if !items.len().is_multiple_of(2) {
        return Err("a dict item without its value".into());
    }
    let mut out = Vec::with_capacity(items.len() / 2);
    let mut it = items.into_iter();
    while let (Some(k), Some(v)) = (it.next(), it.next()) {
        out.push((k, v));
    }
    Ok(out)
}

/// Protocol 2 writes bytes as `_codecs.encode(text, "latin1")`: the bytes themselves.
fn latin1_bytes(callable: &Value, args: &Value) -> Option<Value> {
    let (Value::Global { module, name }, Value::Tuple(a)) = (callable, args) else {
        return None;
    };
    match (module.as_str(), name.as_str(), a.as_slice()) {
        ("_codecs", "encode", [Value::Str(s), Value::Str(enc)]) if enc == "latin1" || enc == "latin-1" => s
            .chars()
            .map(|c| u8::try_from(u32::from(c)).ok())
            .collect::<Option<Vec<u8>>>()
            .map(Value::Bytes),
        _ => None,
    }
}

/// A NumPy array (or scalar, with an empty shape) of numbers, widened to f64.
#[derive(Debug, Clone, PartialEq)]
pub struct Array {
    /// Dimensions.
    pub shape: Vec<usize>,
    /// Values in C order.
    pub data: Vec<f64>,
}

/// Reads a NumPy array (`numpy.core.multiarray._reconstruct` built with its state), a NumPy
/// scalar (`numpy.core.multiarray.scalar`), or a plain int or float, as numbers.
pub fn ndarray(v: &Value) -> Result<Array, String> {
    match v {
        Value::Int(i) => Ok(Array {
            shape: Vec::new(),
            data: vec![*i as f64],
        }),
        Value::Float(f) => Ok(Array {
            shape: Vec::new(),
            data: vec![*f],
        }),
        Value::Call {
            callable,
            args,
            state,
            ..
        } => {
            let Value::Global { module, name } = callable.as_ref() else {
                return Err(format!("{}, not a NumPy array", v.kind()));
            };
            // Protocol 5: numpy.core.numeric._frombuffer(buffer, dtype, shape, order).
            if matches!(module.as_str(), "numpy.core.numeric" | "numpy._core.numeric")
                && name == "_frombuffer"
            {
                return match args.as_ref() {
                    Value::Tuple(a) => match a.as_slice() {
                        [Value::Bytes(b), dtype, Value::Tuple(shape), Value::Str(order)] => {
                            if order != "C" && shape.len() > 1 {
                                return Err("a Fortran-ordered array (C order expected)".into());
                            }
                            numbers(dtype, b, dimensions(shape)?)
                        }
                        _ => Err("a NumPy buffer without (data, dtype, shape, order)".into()),
                    },
                    _ => Err("a NumPy buffer without its arguments".into()),
                };
            }
            if !matches!(
                module.as_str(),
                "numpy.core.multiarray" | "numpy._core.multiarray"
            ) {
                return Err(format!("{module}.{name}, not a NumPy array"));
            }
            match (name.as_str(), args.as_ref(), state.as_deref()) {
                ("scalar", Value::Tuple(a), _) => match a.as_slice() {
                    [dtype, Value::Bytes(b)] => numbers(dtype, b, Vec::new()),
                    _ => Err("a NumPy scalar without its dtype and bytes".into()),
                },
                ("_reconstruct", _, Some(Value::Tuple(s))) => match s.as_slice() {
                    [
                        _,
                        Value::Tuple(shape),
                        dtype,
                        Value::Bool(fortran),
                        Value::Bytes(b),
                    ] => {
                        if *fortran && shape.len() > 1 {
                            return Err("a Fortran-ordered array (C order expected)".into());
                        }
                        numbers(dtype, b, dimensions(shape)?)
                    }
                    [_, _, _, _, Value::List(_)] => Err("an array of Python objects, not numbers".into()),
                    _ => {
                        Err("a NumPy array whose state is not (version, shape, dtype, fortran, data)".into())
                    }
                },
                _ => Err(format!("{module}.{name} without the state of an array")),
            }
        }
        other => Err(format!("{}, not a NumPy array", other.kind())),
    }
}

/// A shape's dimensions.
fn dimensions(shape: &[Value]) -> Result<Vec<usize>, String> {
    shape
        .iter()
        .map(|d| match d {
            Value::Int(n) => usize::try_from(*n).map_err(|_| format!("dimension {n}")),
            other => Err(format!("a dimension that is {}", other.kind())),
        })
        .collect()
}

/// Reads one number from its bytes, big-endian or not.
type ReadNumber = fn(&[u8], bool) -> f64;

/// `bytes` as numbers of `dtype` (a `numpy.dtype(name)` with its byte order), in `shape`.
fn numbers(dtype: &Value, bytes: &[u8], shape: Vec<usize>) -> Result<Array, String> {
    let Value::Call {
        callable,
        args,
        state,
        ..
    } = dtype
    else {
        return Err(format!("a dtype that is {}", dtype.kind()));
    };
    let is_dtype =
        matches!(callable.as_ref(), Value::Global { module, name } if module == "numpy" && name == "dtype");
    let name = match args.as_ref() {
        Value::Tuple(a) if is_dtype => a.first().and_then(Value::as_str).unwrap_or(""),
        _ => "",
    };
    // The state's second field is the byte order ('<', '>', '|' or '=').
    let order = match state.as_deref() {
        Some(Value::Tuple(s)) => s.get(1).and_then(Value::as_str).unwrap_or("<"),
        _ => "<",
    };
    let name = name.trim_start_matches(['<', '>', '=', '|']);
    let big = order == ">";
    let (size, read): (usize, ReadNumber) = match name {
        "f8" => (8, |b, big| {
            let a = std::array::from_fn(|i| b[i]);
            if big {
                f64::from_be_bytes(a)
            } else {
                f64::from_le_bytes(a)
            }
        }),
        "f4" => (4, |b, big| {
            let a = std::array::from_fn(|i| b[i]);
            f64::from(if big {
                f32::from_be_bytes(a)
            } else {
                f32::from_le_bytes(a)
            })
        }),
        "i8" => (8, |b, big| {
            let a = std::array::from_fn(|i| b[i]);
            (if big {
                i64::from_be_bytes(a)
            } else {
                i64::from_le_bytes(a)
            }) as f64
        }),
        "i4" => (4, |b, big| {
            let a = std::array::from_fn(|i| b[i]);
            f64::from(if big {
                i32::from_be_bytes(a)
            } else {
                i32::from_le_bytes(a)
            })
        }),
        other => return Err(format!("dtype {other:?} (numbers of f8, f4, i8 or i4 expected)")),
    };
    let count = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .ok_or("a shape too large")?;
    if count.checked_mul(size) != Some(bytes.len()) {
        return Err(format!(
            "shape {shape:?} of {name} needs {} bytes, the array holds {}",
            count.saturating_mul(size),
            bytes.len()
        ));
    }
    Ok(Array {
        shape,
        data: bytes.chunks_exact(size).map(|c| read(c, big)).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A protocol-4 pickle of `{"fps": 30.0, "a": [1, "x"]}` as CPython writes it.
    const SMALL: &[u8] = b"\x80\x04\x95\x22\x00\x00\x00\x00\x00\x00\x00}\x94(\x8c\x03fps\x94G@>\x00\x00\x00\x00\x00\x00\x8c\x01a\x94]\x94(K\x01\x8c\x01x\x94eu.";

    #[test]
    fn a_dict_of_plain_values_reads_back() {
        let v = read(SMALL).unwrap();
        assert_eq!(v.get("fps"), Some(&Value::Float(30.0)));
        assert_eq!(
            v.get("a"),
            Some(&Value::List(vec![Value::Int(1), Value::Str("x".into())]))
        );
    }

    #[test]
    fn truncated_or_hostile_streams_are_errors_not_panics() {
        for cut in 0..SMALL.len() {
            assert!(read(&SMALL[..cut]).is_err(), "cut at {cut}");
        }
        // A memo copy doubled forty times: refused by the value budget, not built.
        let mut bomb = b"\x80\x04N\x94".to_vec();
        for _ in 0..40 {
            bomb.extend_from_slice(b"h\x00h\x00\x86q\x00\x30");
        }
        let e = read(&bomb).unwrap_err();
        assert!(
            e.message.contains("more than") || e.message.contains("nest"),
            "{e}"
        );
        // Code is never run: REDUCE stays data, and an unknown opcode is refused.
        assert!(read(b"\x80\x04\x8c\x02os\x8c\x06system\x93\x8c\x02ls\x85R.").is_ok());
        assert!(read(b"\x80\x04I1\n.").is_err());
    }
}
