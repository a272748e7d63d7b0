//! A minimal, safe interpreter for the subset of Python's pickle format
//! (protocol 2) that `torch.save(model.state_dict())` produces: dicts,
//! tuples, small ints, strings, booleans, `GLOBAL` references and
//! persistent ids for tensor storages. Globals are never executed: they are
//! kept as names, and `REDUCE` of a global is kept as a call record for the
//! caller to interpret. See the `pickletools` module docs for the opcodes.

/// A pickled value.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Value {
    /// `None`.
    None,
    /// A boolean.
    Bool(bool),
    /// An integer.
    Int(i64),
    /// A float.
    Float(f64),
    /// A string.
    Str(String),
    /// A tuple or list.
    Tuple(Vec<Value>),
    /// A dict as ordered key/value pairs.
    Dict(Vec<(Value, Value)>),
    /// A `module.name` global (never resolved or executed).
    Global(String),
    /// `callable(*args)` as recorded by `REDUCE`.
    Call(Box<Value>, Vec<Value>),
    /// A persistent id (`BINPERSID`): torch uses it for storages.
    PersId(Box<Value>),
    /// The stack marker of `MARK`.
    Mark,
}

/// Largest memo index accepted (a torch state dict uses a few thousand).
const MAX_MEMO: usize = 1 << 20;

/// Runs the pickle program `b` and returns the value left by `STOP`.
pub(crate) fn load(b: &[u8]) -> Result<Value, String> {
    let mut stack: Vec<Value> = Vec::new();
    let mut memo: Vec<Option<Value>> = Vec::new();
    let mut pos = 0usize;
    let take = |pos: &mut usize, n: usize| -> Result<&[u8], String> {
        let s = b.get(*pos..*pos + n).ok_or_else(|| format!("truncated at byte {}", *pos))?;
        *pos += n;
        Ok(s)
    };
    let pop = |stack: &mut Vec<Value>| stack.pop().ok_or_else(|| "stack underflow".to_string());
    let pop_mark = |stack: &mut Vec<Value>| -> Result<Vec<Value>, String> {
        let m = stack.iter().rposition(|v| *v == Value::Mark).ok_or("MARK not found")?;
        let items = stack.split_off(m + 1);
        stack.pop(); // the mark itself, present by rposition
        Ok(items)
    };
    loop {
        let op = *take(&mut pos, 1)?.first().ok_or("empty")?;
        match op {
            0x80 => {
                take(&mut pos, 1)?; // PROTO n
            }
            b'.' => return pop(&mut stack), // STOP
            b'(' => stack.push(Value::Mark),
            b'N' => stack.push(Value::None),
            0x88 => stack.push(Value::Bool(true)),
            0x89 => stack.push(Value::Bool(false)),
            b'K' => stack.push(Value::Int(i64::from(take(&mut pos, 1)?[0]))),
            b'M' => {
                let s = take(&mut pos, 2)?;
                stack.push(Value::Int(i64::from(u16::from_le_bytes([s[0], s[1]]))));
            }
            b'J' => {
                let s = take(&mut pos, 4)?;
                stack.push(Value::Int(i64::from(i32::from_le_bytes([s[0], s[1], s[2], s[3]]))));
            }
            0x8a => {
                // LONG1: n bytes little-endian two's complement.
                let n = take(&mut pos, 1)?[0] as usize;
                let s = take(&mut pos, n)?;
                if n > 8 {
                    return Err(format!("LONG1 of {n} bytes is too large"));
                }
                let mut v: i64 = 0;
                for (i, &byte) in s.iter().enumerate() {
                    v |= i64::from(byte) << (8 * i);
                }
                if n > 0 && n < 8 && s[n - 1] & 0x80 != 0 {
                    v -= 1i64 << (8 * n);
                }
                stack.push(Value::Int(v));
            }
            b'G' => {
                let s = take(&mut pos, 8)?;
                let a: [u8; 8] = s.try_into().map_err(|_| "BINFLOAT")?;
                stack.push(Value::Float(f64::from_be_bytes(a)));
            }
            b'X' => {
                let s = take(&mut pos, 4)?;
                let n = u32::from_le_bytes([s[0], s[1], s[2], s[3]]) as usize;
                let s = take(&mut pos, n)?;
                stack.push(Value::Str(String::from_utf8_lossy(s).into_owned()));
            }
            0x8c => {
                // SHORT_BINUNICODE
                let n = take(&mut pos, 1)?[0] as usize;
                let s = take(&mut pos, n)?;
                stack.push(Value::Str(String::from_utf8_lossy(s).into_owned()));
            }
            b'c' => {
                // GLOBAL "module\nname\n"
                let line = |pos: &mut usize| -> Result<String, String> {
                    let rest = b.get(*pos..).ok_or("truncated GLOBAL")?;
                    let end = rest.iter().position(|&c| c == b'\n').ok_or("unterminated GLOBAL")?;
                    let s = String::from_utf8_lossy(&rest[..end]).into_owned();
                    *pos += end + 1;
                    Ok(s)
                };
                let module = line(&mut pos)?;
                let name = line(&mut pos)?;
                stack.push(Value::Global(format!("{module}.{name}")));
            }
            b')' => stack.push(Value::Tuple(Vec::new())),
            b']' => stack.push(Value::Tuple(Vec::new())),
            b'}' => stack.push(Value::Dict(Vec::new())),
            b't' | b'l' => {
                let items = pop_mark(&mut stack)?;
                stack.push(Value::Tuple(items));
            }
            0x85 => {
                let a = pop(&mut stack)?;
                stack.push(Value::Tuple(vec![a]));
            }
            0x86 => {
                let b2 = pop(&mut stack)?;
                let a = pop(&mut stack)?;
                stack.push(Value::Tuple(vec![a, b2]));
            }
            0x87 => {
                let c = pop(&mut stack)?;
                let b2 = pop(&mut stack)?;
                let a = pop(&mut stack)?;
                stack.push(Value::Tuple(vec![a, b2, c]));
            }
            b'a' => {
                let v = pop(&mut stack)?;
                match stack.last_mut() {
                    Some(Value::Tuple(items)) => items.push(v),
                    _ => return Err("APPEND to a non-list".into()),
                }
            }
            b'e' => {
                let vs = pop_mark(&mut stack)?;
                match stack.last_mut() {
                    Some(Value::Tuple(items)) => items.extend(vs),
                    _ => return Err("APPENDS to a non-list".into()),
                }
            }
            b's' => {
                let v = pop(&mut stack)?;
                let k = pop(&mut stack)?;
                match stack.last_mut() {
                    Some(Value::Dict(items)) => items.push((k, v)),
                    _ => return Err("SETITEM on a non-dict".into()),
                }
            }
            b'u' => {
                let vs = pop_mark(&mut stack)?;
                if vs.len() % 2 != 0 {
                    return Err("SETITEMS with an odd number of items".into());
                }
                let mut it = vs.into_iter();
                let mut pairs = Vec::new();
                while let (Some(k), Some(v)) = (it.next(), it.next()) {
                    pairs.push((k, v));
                }
                match stack.last_mut() {
                    Some(Value::Dict(items)) => items.extend(pairs),
                    _ => return Err("SETITEMS on a non-dict".into()),
                }
            }
            b'R' => {
                let args = pop(&mut stack)?;
                let f = pop(&mut stack)?;
                let args = match args {
                    Value::Tuple(a) => a,
                    other => return Err(format!("REDUCE with non-tuple arguments {other:?}")),
                };
                // OrderedDict() is just an empty dict for our purposes.
                if f == Value::Global("collections.OrderedDict".into()) && args.is_empty() {
                    stack.push(Value::Dict(Vec::new()));
                } else {
                    stack.push(Value::Call(Box::new(f), args));
                }
            }
            b'b' => {
                // BUILD: sets state on the object below; state dicts carry
                // only `_metadata` there, which we do not need.
                pop(&mut stack)?;
            }
            b'Q' => {
                let pid = pop(&mut stack)?;
                stack.push(Value::PersId(Box::new(pid)));
            }
            b'q' | b'r' | b'p' => {
                let idx = match op {
                    b'q' => take(&mut pos, 1)?[0] as usize,
                    b'r' => {
                        let s = take(&mut pos, 4)?;
                        u32::from_le_bytes([s[0], s[1], s[2], s[3]]) as usize
                    }
                    _ => return Err("text PUT is not supported".into()),
                };
                if idx >= MAX_MEMO {
                    return Err(format!("memo index {idx} is too large"));
                }
                let top = stack.last().ok_or("PUT on an empty stack")?.clone();
                if memo.len() <= idx {
                    memo.resize(idx + 1, None);
                }
                memo[idx] = Some(top);
            }
            b'h' | b'j' => {
                let idx = if op == b'h' {
                    take(&mut pos, 1)?[0] as usize
                } else {
                    let s = take(&mut pos, 4)?;
                    u32::from_le_bytes([s[0], s[1], s[2], s[3]]) as usize
                };
                let v = memo.get(idx).and_then(|v| v.clone()).ok_or_else(|| format!("memo {idx} is empty"))?;
                stack.push(v);
            }
            b'0' => {
                pop(&mut stack)?;
            }
            other => {
                return Err(format!("unsupported pickle opcode 0x{other:02x} at byte {}", pos - 1));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_a_small_dict() {
        // pickle.dumps({'a': (1, 300, -2), 'b': 'xy'}, protocol=2)
        let p: &[u8] = b"\x80\x02}q\x00(X\x01\x00\x00\x00aq\x01K\x01M,\x01J\xfe\xff\xff\xff\x87q\x02X\x01\x00\x00\x00bq\x03X\x02\x00\x00\x00xyq\x04u.";
        let v = load(p).unwrap();
        assert_eq!(
            v,
            Value::Dict(vec![
                (Value::Str("a".into()), Value::Tuple(vec![Value::Int(1), Value::Int(300), Value::Int(-2)])),
                (Value::Str("b".into()), Value::Str("xy".into())),
            ])
        );
    }

    #[test]
    fn rejects_garbage_without_panicking() {
        for bad in
            [&b""[..], b"\x80", b"\x80\x02(", b"\x80\x02\xff", b"\x80\x02h\x05.", b"\x80\x02X\xff\xff\xff\xff", b"u."]
        {
            assert!(load(bad).is_err(), "{bad:?}");
        }
    }
}
