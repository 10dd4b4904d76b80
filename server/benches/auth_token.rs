//! Cost of minting and checking a token: verify runs once per `Hello`.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use strata_protocol::Role;
use strata_server::auth::{issue, verify, Secret};

fn bench_tokens(c: &mut Criterion) {
    let secret = Secret::from_bytes([9; 32]);
    let now = 1_800_000_000;
    let ttl = Duration::from_secs(3600);
    let token = issue(&secret, "benchmark_player", Role::Player, ttl, now).unwrap();
    c.bench_function("token_issue", |b| {
        b.iter(|| {
            issue(
                &secret,
                black_box("benchmark_player"),
                Role::Player,
                ttl,
                now,
            )
            .unwrap()
        })
    });
    c.bench_function("token_verify", |b| {
        b.iter(|| verify(&secret, black_box(&token), now + 1).unwrap())
    });
}

criterion_group!(benches, bench_tokens);
criterion_main!(benches);
