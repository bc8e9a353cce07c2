//! A client of openpi's policy server (`openpi.serving.websocket_policy_server`), its
//! protocol written from its documentation and source:
//!
//! - one WebSocket connection (plain `ws://`, no compression); on connect the server sends
//!   one binary frame: its metadata (a msgpack map);
//! - each request is one binary frame, a msgpack map of the observation; the answer is one
//!   binary frame, a msgpack map holding `actions` (H × D);
//! - numpy arrays travel as msgpack maps with byte-string (bin) keys `__ndarray__` (true),
//!   `data` (the C-order bytes), `dtype` (numpy's `dtype.str`, e.g. `<f4`) and `shape`; numpy
//!   scalars as `__npgeneric__`, `data`, `dtype` (openpi-client's `msgpack_numpy`);
//! - a server that fails sends a text frame (its traceback) and closes the connection.
//!
//! The observation keys are the reference's openpi adapter's: `am_bench/<state key>` as
//! float32 vectors, `am_bench/ee_image` (and `am_bench/base_image`) as uint8 H × W × 3, and
//! `prompt` as a string.

use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use rmpv::Value;
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

use super::chunk::ActionChunk;
use super::{Policy, PolicyError, PolicyObservation};

/// The observation keys' prefix (the reference's adapter).
pub const KEY_PREFIX: &str = "am_bench/";

/// A connection to an openpi policy server.
pub struct OpenpiClient {
    url: String,
    runtime: tokio::runtime::Runtime,
    socket: Option<WebSocketStream<MaybeTlsStream<TcpStream>>>,
    metadata: Value,
    query_timeout: Duration,
}

impl std::fmt::Debug for OpenpiClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpenpiClient")
            .field("url", &self.url)
            .field("metadata", &self.metadata)
            .finish_non_exhaustive()
    }
}

impl OpenpiClient {
    /// Connects to `url` (`ws://HOST:PORT`) and reads the server's metadata frame, within
    /// `connect_timeout`; each later answer may take `query_timeout`.
    pub fn connect(
        url: &str,
        connect_timeout: Duration,
        query_timeout: Duration,
    ) -> Result<Self, PolicyError> {
        let fail = |what: String| PolicyError(format!("policy server {url}: {what}"));
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_io()
            .enable_time()
            .build()
            .map_err(|e| fail(format!("cannot start the client: {e}")))?;
        let (socket, metadata) = runtime.block_on(async {
            let connected =
                tokio::time::timeout(connect_timeout, tokio_tungstenite::connect_async(url))
                    .await
                    .map_err(|_| {
                        fail(format!(
                            "no connection in {} ms",
                            connect_timeout.as_millis()
                        ))
                    })?
                    .map_err(|e| fail(format!("cannot connect: {e}")))?;
            let mut socket = connected.0;
            let first = receive(&mut socket, connect_timeout)
                .await
                .map_err(|e| fail(format!("metadata: {e}")))?;
            let metadata = decode(&first).map_err(|e| fail(format!("metadata: {e}")))?;
            Ok::<_, PolicyError>((socket, metadata))
        })?;
        Ok(Self {
            url: url.to_owned(),
            runtime,
            socket: Some(socket),
            metadata,
            query_timeout,
        })
    }

    /// The metadata the server sent on connect.
    pub fn metadata(&self) -> &Value {
        &self.metadata
    }
}

impl Drop for OpenpiClient {
    fn drop(&mut self) {
        // Close politely (best effort: the server may be gone).
        if let Some(mut socket) = self.socket.take() {
            // The timer is made inside the runtime (its reactor).
            let _ = self.runtime.block_on(async {
                tokio::time::timeout(Duration::from_millis(200), socket.close(None)).await
            });
        }
    }
}

/// The next data frame's bytes: a text frame is the server's error, a close its end.
async fn receive(
    socket: &mut WebSocketStream<MaybeTlsStream<TcpStream>>,
    timeout: Duration,
) -> Result<Vec<u8>, String> {
    loop {
        let message = tokio::time::timeout(timeout, socket.next())
            .await
            .map_err(|_| format!("no answer in {} ms", timeout.as_millis()))?;
        match message {
            None => return Err("the server closed the connection".to_owned()),
            Some(Err(e)) => return Err(format!("connection lost: {e}")),
            Some(Ok(Message::Binary(bytes))) => return Ok(bytes.to_vec()),
            Some(Ok(Message::Text(text))) => {
                let last = text
                    .as_str()
                    .lines()
                    .rev()
                    .find(|l| !l.trim().is_empty())
                    .unwrap_or("")
                    .trim()
                    .to_owned();
                return Err(format!("server error: {last}"));
            }
            Some(Ok(Message::Close(frame))) => {
                return Err(match frame {
                    Some(f) if !f.reason.as_str().is_empty() => {
                        format!("the server closed the connection ({})", f.reason.as_str())
                    }
                    _ => "the server closed the connection".to_owned(),
                });
            }
            Some(Ok(_)) => {} // ping, pong: the library answers them
        }
    }
}

impl Policy for OpenpiClient {
    fn query(&mut self, observation: &PolicyObservation<'_>) -> Result<ActionChunk, PolicyError> {
        let url = self.url.clone();
        let fail = |what: String| PolicyError(format!("policy server {url}: {what}"));
        let frame = encode(&observation_value(observation));
        let timeout = self.query_timeout;
        let socket = self
            .socket
            .as_mut()
            .ok_or_else(|| fail("not connected".to_owned()))?;
        let reply = self.runtime.block_on(async {
            tokio::time::timeout(timeout, socket.send(Message::Binary(frame.into())))
                .await
                .map_err(|_| format!("request not sent in {} ms", timeout.as_millis()))?
                .map_err(|e| format!("cannot send: {e}"))?;
            receive(socket, timeout).await
        });
        let reply = reply.map_err(fail)?;
        let value = decode(&reply).map_err(fail)?;
        let actions = map_get(&value, "actions")
            .ok_or_else(|| fail("the answer has no `actions`".to_owned()))?;
        let (shape, values) = ndarray_f64(actions).map_err(|e| fail(format!("actions: {e}")))?;
        match shape[..] {
            [rows, dim] => Ok(ActionChunk { rows, dim, values }),
            _ => Err(fail(format!(
                "wrong shape: actions {shape:?}, expected (H, D)"
            ))),
        }
    }
}

/// msgpack bytes of `value`.
pub fn encode(value: &Value) -> Vec<u8> {
    let mut out = Vec::new();
    // Writing into a Vec cannot fail.
    let _ = rmpv::encode::write_value(&mut out, value);
    out
}

/// The msgpack value in `bytes` (exactly one).
pub fn decode(bytes: &[u8]) -> Result<Value, String> {
    let mut rest = bytes;
    let value = rmpv::decode::read_value(&mut rest).map_err(|e| format!("not msgpack: {e}"))?;
    if !rest.is_empty() {
        return Err(format!("{} bytes after the msgpack value", rest.len()));
    }
    Ok(value)
}

/// The entry `key` of a map (its key a string or a byte string).
pub fn map_get<'a>(value: &'a Value, key: &str) -> Option<&'a Value> {
    let Value::Map(entries) = value else {
        return None;
    };
    entries.iter().find_map(|(k, v)| {
        let matches = match k {
            Value::String(s) => s.as_str() == Some(key),
            Value::Binary(b) => b.as_slice() == key.as_bytes(),
            _ => false,
        };
        matches.then_some(v)
    })
}

/// A numpy array as openpi-client's `msgpack_numpy` packs it.
pub fn ndarray(dtype: &str, shape: &[usize], data: Vec<u8>) -> Value {
    Value::Map(vec![
        (Value::Binary(b"__ndarray__".to_vec()), Value::Boolean(true)),
        (Value::Binary(b"data".to_vec()), Value::Binary(data)),
        (
            Value::Binary(b"dtype".to_vec()),
            Value::String(dtype.into()),
        ),
        (
            Value::Binary(b"shape".to_vec()),
            Value::Array(shape.iter().map(|&n| Value::from(n as u64)).collect()),
        ),
    ])
}

/// A float32 vector as a numpy array.
pub fn f32_array(values: &[f64]) -> Value {
    // float32 on the wire, as the reference's adapter sends its state.
    #[allow(clippy::cast_possible_truncation, reason = "float32 on the wire")]
    let data: Vec<u8> = values
        .iter()
        .flat_map(|v| (*v as f32).to_le_bytes())
        .collect();
    ndarray("<f4", &[values.len()], data)
}

/// The request of one observation.
pub fn observation_value(observation: &PolicyObservation<'_>) -> Value {
    let mut entries: Vec<(Value, Value)> = observation
        .state
        .iter()
        .map(|(key, values)| {
            (
                Value::String(format!("{KEY_PREFIX}{}", key.name()).into()),
                f32_array(values),
            )
        })
        .collect();
    for image in observation.images {
        entries.push((
            Value::String(format!("{KEY_PREFIX}{}", image.key).into()),
            ndarray("|u1", &[image.height, image.width, 3], image.rgb.clone()),
        ));
    }
    entries.push((
        Value::String("prompt".into()),
        Value::String(observation.prompt.into()),
    ));
    Value::Map(entries)
}

/// The shape and values (as f64) of a numeric numpy array or scalar packed by
/// `msgpack_numpy` (little-endian or single-byte dtypes).
pub fn ndarray_f64(value: &Value) -> Result<(Vec<usize>, Vec<f64>), String> {
    let dtype = map_get(value, "dtype")
        .and_then(Value::as_str)
        .ok_or("not a numpy array (no dtype)")?;
    if map_get(value, "__npgeneric__").is_some() {
        let data = map_get(value, "data").ok_or("numpy scalar without data")?;
        let x = data
            .as_f64()
            .or_else(|| data.as_i64().map(|i| i as f64))
            .or_else(|| data.as_u64().map(|u| u as f64))
            .ok_or_else(|| format!("numpy scalar {dtype} is not a number"))?;
        return Ok((Vec::new(), vec![x]));
    }
    if map_get(value, "__ndarray__").is_none() {
        return Err("not a numpy array (no __ndarray__)".to_owned());
    }
    let data = map_get(value, "data")
        .and_then(Value::as_slice)
        .ok_or("numpy array without data bytes")?;
    let shape: Vec<usize> = map_get(value, "shape")
        .and_then(Value::as_array)
        .ok_or("numpy array without shape")?
        .iter()
        .map(|n| n.as_u64().and_then(|n| usize::try_from(n).ok()))
        .collect::<Option<_>>()
        .ok_or("numpy shape is not a list of sizes")?;
    let (order, kind) = dtype.split_at(1.min(dtype.len()));
    if order == ">" {
        return Err(format!("big-endian dtype {dtype} not supported"));
    }
    let width: usize = match kind {
        "f2" | "i2" | "u2" => 2,
        "f4" | "i4" | "u4" => 4,
        "f8" | "i8" | "u8" => 8,
        "u1" | "i1" | "b1" => 1,
        _ => return Err(format!("dtype {dtype} not supported (numbers only)")),
    };
    let count: usize = shape.iter().product();
    if data.len() != count * width {
        return Err(format!(
            "{} data bytes for shape {shape:?} of {dtype} ({} expected)",
            data.len(),
            count * width
        ));
    }
    let values = data
        .chunks_exact(width)
        .map(|b| {
            let mut le = [0u8; 8];
            le[..width].copy_from_slice(b);
            match kind {
                "f8" => f64::from_le_bytes(le),
                "f4" => f64::from(f32::from_le_bytes([le[0], le[1], le[2], le[3]])),
                "f2" => half_to_f64(u16::from_le_bytes([le[0], le[1]])),
                "i8" => i64::from_le_bytes(le) as f64,
                "i4" => f64::from(i32::from_le_bytes([le[0], le[1], le[2], le[3]])),
                "i2" => f64::from(i16::from_le_bytes([le[0], le[1]])),
                "i1" => f64::from(i8::from_le_bytes([le[0]])),
                "u8" => u64::from_le_bytes(le) as f64,
                "u4" => f64::from(u32::from_le_bytes([le[0], le[1], le[2], le[3]])),
                "u2" => f64::from(u16::from_le_bytes([le[0], le[1]])),
                _ => f64::from(le[0]),
            }
        })
        .collect();
    Ok((shape, values))
}

/// An IEEE 754 half-precision number.
fn half_to_f64(bits: u16) -> f64 {
    let sign = if bits & 0x8000 == 0 { 1.0 } else { -1.0 };
    let exponent = i32::from((bits >> 10) & 0x1f);
    let mantissa = f64::from(bits & 0x3ff);
    match exponent {
        0 => sign * mantissa * 2f64.powi(-24),
        31 if mantissa == 0.0 => sign * f64::INFINITY,
        31 => f64::NAN,
        e => sign * (1.0 + mantissa / 1024.0) * 2f64.powi(e - 15),
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;
    use crate::policy::StateKey;

    #[test]
    fn an_observation_packs_as_msgpack_numpy() {
        let state = [(StateKey::EePos, vec![1.0, 2.0, 3.0])];
        let value = observation_value(&PolicyObservation {
            state: &state,
            prompt: "press the button",
            images: &[],
        });
        let bytes = encode(&value);
        // fixmap(2), fixstr "am_bench/ee_pos", fixmap(4) with bin8 keys.
        assert_eq!(bytes[0], 0x82);
        assert_eq!(&bytes[2..17], b"am_bench/ee_pos");
        assert_eq!(bytes[17], 0x84);
        assert_eq!(&bytes[18..21], &[0xc4, 11, b'_']);
        let back = decode(&bytes).unwrap();
        let array = map_get(&back, "am_bench/ee_pos").unwrap();
        assert_eq!(ndarray_f64(array).unwrap(), (vec![3], vec![1.0, 2.0, 3.0]));
        assert_eq!(
            map_get(&back, "prompt").and_then(Value::as_str),
            Some("press the button")
        );
    }

    #[test]
    fn arrays_decode_by_dtype_and_refuse_a_short_buffer() {
        let f8: Vec<u8> = [0.5f64, -2.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let v = ndarray("<f8", &[1, 2], f8);
        assert_eq!(ndarray_f64(&v).unwrap(), (vec![1, 2], vec![0.5, -2.0]));
        // float16 1.0 = 0x3c00, −2.0 = 0xc000.
        let f2 = ndarray("<f2", &[2], vec![0x00, 0x3c, 0x00, 0xc0]);
        assert_eq!(ndarray_f64(&f2).unwrap().1, vec![1.0, -2.0]);
        let short = ndarray("<f4", &[2], vec![0; 4]);
        assert!(ndarray_f64(&short).unwrap_err().contains("4 data bytes"));
        let object = ndarray("|O", &[1], vec![0]);
        assert!(ndarray_f64(&object).unwrap_err().contains("not supported"));
        let scalar = Value::Map(vec![
            (
                Value::Binary(b"__npgeneric__".to_vec()),
                Value::Boolean(true),
            ),
            (Value::Binary(b"data".to_vec()), Value::F64(0.25)),
            (
                Value::Binary(b"dtype".to_vec()),
                Value::String("<f8".into()),
            ),
        ]);
        assert_eq!(ndarray_f64(&scalar).unwrap(), (vec![], vec![0.25]));
    }
}
