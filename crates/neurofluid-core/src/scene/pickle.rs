//! Writes the box as a plain Python pickle (protocol 3) of
//! `{'box': ndarray f32 (N,3), 'box_normals': ndarray f32 (N,3)}`, the shape of NeuroFluid's
//! `box.pt`, so a generated scene also loads in the original code (`joblib.load` reads plain
//! pickles). The arrays are encoded the way numpy pickles them (`_reconstruct` + state).

use super::particles::BoxParticles;

fn global(out: &mut Vec<u8>, module: &str, name: &str) {
    out.push(b'c');
    out.extend_from_slice(module.as_bytes());
    out.push(b'\n');
    out.extend_from_slice(name.as_bytes());
    out.push(b'\n');
}

fn unicode(out: &mut Vec<u8>, s: &str) {
    out.push(b'X');
    out.extend_from_slice(&(s.len() as u32).to_le_bytes());
    out.extend_from_slice(s.as_bytes());
}

fn int(out: &mut Vec<u8>, v: i32) {
    out.push(b'J');
    out.extend_from_slice(&v.to_le_bytes());
}

fn array(out: &mut Vec<u8>, rows: &[[f32; 3]]) {
    // _reconstruct(ndarray, (0,), b'b')
    global(out, "numpy.core.multiarray", "_reconstruct");
    global(out, "numpy", "ndarray");
    out.extend_from_slice(b"K\x00\x85");
    out.extend_from_slice(b"C\x01b");
    out.extend_from_slice(b"\x87R");
    // state (1, (N, 3), dtype('<f4'), False, raw bytes)
    out.push(b'(');
    out.extend_from_slice(b"K\x01");
    int(out, rows.len() as i32);
    out.extend_from_slice(b"K\x03\x86");
    global(out, "numpy", "dtype");
    unicode(out, "f4");
    out.extend_from_slice(b"\x89\x88\x87R");
    out.push(b'(');
    out.extend_from_slice(b"K\x03");
    unicode(out, "<");
    out.extend_from_slice(b"NNN");
    int(out, -1);
    int(out, -1);
    out.extend_from_slice(b"K\x00tb");
    out.push(0x89);
    let raw: Vec<u8> = rows
        .as_flattened()
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    out.push(b'B');
    out.extend_from_slice(&(raw.len() as u32).to_le_bytes());
    out.extend_from_slice(&raw);
    out.extend_from_slice(b"tb");
}

/// The pickle bytes of `{'box': points, 'box_normals': normals}`.
pub fn box_pickle(b: &BoxParticles) -> Vec<u8> {
    let mut out = vec![0x80, 0x03, b'}', b'('];
    unicode(&mut out, "box");
    array(&mut out, &b.points);
    unicode(&mut out, "box_normals");
    array(&mut out, &b.normals);
    out.extend_from_slice(b"u.");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Layout check; the bytes were also loaded with Python's `pickle.load` (numpy 2.4, warnings
    /// as errors) and compared equal to the `.npz` arrays.
    #[test]
    fn pickle_layout() {
        let b = BoxParticles {
            points: vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]],
            normals: vec![[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]],
        };
        let p = box_pickle(&b);
        assert_eq!(&p[..4], b"\x80\x03}(");
        assert_eq!(&p[p.len() - 2..], b"u.");
        let raw: Vec<u8> = b
            .points
            .as_flattened()
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let mut binbytes = vec![b'B'];
        binbytes.extend_from_slice(&24u32.to_le_bytes());
        binbytes.extend_from_slice(&raw);
        let at = p
            .windows(binbytes.len())
            .position(|w| w == binbytes.as_slice());
        assert!(at.is_some(), "raw point bytes not found");
        // both arrays: two _reconstruct globals, two dtype globals
        let count = |needle: &[u8]| p.windows(needle.len()).filter(|w| *w == needle).count();
        assert_eq!(count(b"cnumpy.core.multiarray\n_reconstruct\n"), 2);
        assert_eq!(count(b"cnumpy\ndtype\n"), 2);
        // opening MARKs and closing TUPLE/BUILD pairs balance: 1 dict MARK + 2×2 per array
        assert_eq!(count(b"tb"), 4);
    }
}
