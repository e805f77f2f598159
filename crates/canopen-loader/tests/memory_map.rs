//! The root `memory.x` (the one statement of the regions) and [`canopen_loader::layout`] say
//! the same.

use canopen_loader::layout::{
    APP_ORIGIN, HANDOFF_LENGTH, HANDOFF_ORIGIN, HEADER_SLOT, LOADER_LENGTH, LOADER_ORIGIN,
    MAX_IMAGE, RAM_LENGTH, RAM_ORIGIN, SLOT_ORIGIN, STORAGE_LENGTH, STORAGE_ORIGIN,
};

/// Evaluates a length or origin of memory.x: hex or decimal numbers, `K` suffixes, `+`, `-`.
fn eval(expr: &str) -> u32 {
    let mut total: i64 = 0;
    let mut sign = 1;
    for token in expr
        .replace('+', " + ")
        .replace('-', " - ")
        .split_whitespace()
    {
        match token {
            "+" => sign = 1,
            "-" => sign = -1,
            t => {
                let (digits, scale) = match t.strip_suffix('K') {
                    Some(d) => (d, 1024),
                    None => (t, 1),
                };
                let value = match digits.strip_prefix("0x") {
                    Some(hex) => i64::from_str_radix(hex, 16).unwrap(),
                    None => digits.parse::<i64>().unwrap(),
                };
                total += sign * value * scale;
            }
        }
    }
    u32::try_from(total).unwrap()
}

/// (origin, length) of every region in the MEMORY block.
fn regions() -> Vec<(String, u32, u32)> {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../memory.x"))
        .expect("the root memory.x");
    let block = text.split("MEMORY").nth(1).unwrap();
    let block = &block[block.find('{').unwrap() + 1..block.find('}').unwrap()];
    block
        .lines()
        .filter(|l| l.contains("ORIGIN"))
        .map(|line| {
            let (name, rest) = line.split_once(':').unwrap();
            let (origin, length) = rest.split_once(',').unwrap();
            let value = |s: &str| eval(s.split_once('=').unwrap().1.trim());
            (name.trim().to_string(), value(origin), value(length))
        })
        .collect()
}

#[test]
fn memory_x_is_the_layout() {
    let r = regions();
    let names: Vec<&str> = r.iter().map(|(n, ..)| n.as_str()).collect();
    assert_eq!(
        names,
        ["LOADER", "HEADER", "FLASH", "STORAGE", "RAM", "HANDOFF"]
    );
    let get = |name: &str| {
        r.iter()
            .find(|(n, ..)| n == name)
            .map(|&(_, o, l)| (o, l))
            .unwrap()
    };
    assert_eq!(get("LOADER"), (LOADER_ORIGIN, LOADER_LENGTH));
    assert_eq!(get("HEADER"), (SLOT_ORIGIN, HEADER_SLOT as u32));
    assert_eq!(get("FLASH"), (APP_ORIGIN, MAX_IMAGE as u32));
    assert_eq!(get("STORAGE"), (STORAGE_ORIGIN, STORAGE_LENGTH));
    assert_eq!(get("RAM"), (RAM_ORIGIN, RAM_LENGTH));
    assert_eq!(get("HANDOFF"), (HANDOFF_ORIGIN, HANDOFF_LENGTH));
    assert_eq!(HANDOFF_ORIGIN, 0x2000_4FF8);
}
