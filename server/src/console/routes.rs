//! The console's HTTP routes. The page and its assets are public (they
//! hold no data); every `/api/` route needs an admin token.
//!
//! - `GET /api/world`: who you are and the world's constants.
//! - `GET /api/tile?view=top|slice&y=Y&tx=X&tz=Z`: a map tile (PNG).
//! - `GET /api/scene.glb?x0&y0&z0&x1&y1&z1`: a chunk box's mesh (GLB).
//! - `GET /api/regions?x0&z0&x1&z1`: who writes each region over chunk
//!   columns (JSON).
//! - `GET /api/events`: server-sent events, one `sample` each period.
//! - `POST /api/action`: a confirmed admin action (JSON).

use std::sync::Arc;
use std::time::Duration;

use axum::body::Body;
use axum::extract::{Request, State};
use axum::http::{header, HeaderMap, HeaderValue, Method, StatusCode, Uri};
use axum::middleware::{self, Next};
use axum::response::sse::{KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use serde_json::json;
use strata_terrain::ChunkPos;
use tracing::{info, Instrument};

use super::actions::{self, ActionError, ActionRequest};
use super::query::Query;
use super::tiles::{self, TileKey, View};
use super::{assets, auth, regions, scene, Console, MAX_TILE_COORD, TILE_COLUMNS};
use crate::admin::world_source::WorldView;

/// Longest wait for a free render slot before answering 503.
const RENDER_WAIT: Duration = Duration::from_secs(20);
/// What the page may load: only its own origin, and images it makes.
const CONTENT_SECURITY_POLICY: &str = "default-src 'self'; img-src 'self' blob: data:; \
     connect-src 'self'; script-src 'self'; style-src 'self'; frame-ancestors 'none'";

pub fn router(console: Arc<Console>) -> Router {
    Router::new()
        .route("/", get(|| async { asset("index.html") }))
        .route("/assets/{name}", get(asset_route))
        .route("/api/world", get(world))
        .route("/api/tile", get(tile))
        .route("/api/scene.glb", get(scene_glb))
        .route("/api/regions", get(regions_route))
        .route("/api/events", get(events))
        .route("/api/action", post(action))
        .layer(middleware::from_fn_with_state(console.clone(), per_request))
        .with_state(console)
}

/// A span per request, and headers that keep the page to its own origin.
/// A request whose admin token checks out admits its connection before it
/// runs (`conn_limit.rs`): from then on it is not closed for a new one
/// while that token stays good.
async fn per_request(State(c): State<Arc<Console>>, req: Request, next: Next) -> Response {
    let span = tracing::info_span!("console", method = %req.method(), path = %req.uri().path());
    let api = req.uri().path().starts_with("/api/");
    if req.headers().contains_key(header::AUTHORIZATION) {
        let conn = req
            .extensions()
            .get::<axum::extract::ConnectInfo<super::ConnMark>>();
        if let (Some(conn), Ok(claims)) = (conn, auth::check(&c.ctx, req.headers())) {
            let ctx = c.ctx.clone();
            conn.0 .0.admit(Box::new(move || {
                auth::still_admitted(&ctx, &claims, crate::auth::unix_now()).is_ok()
            }));
        }
    }
    let mut resp = next.run(req).instrument(span).await;
    let h = resp.headers_mut();
    if api && !h.contains_key(header::CACHE_CONTROL) {
        // The world's seed, who holds what: nothing for a cache to keep.
        h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    }
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(CONTENT_SECURITY_POLICY),
    );
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    h.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    resp
}

/// A refused or failed request: its status and a JSON `{"error": ...}`.
#[derive(Debug)]
struct ApiError(StatusCode, String);

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let body = json!({ "error": self.1 }).to_string();
        (self.0, [(header::CONTENT_TYPE, "application/json")], body).into_response()
    }
}

type ApiResult = Result<Response, ApiError>;

fn error(status: StatusCode, message: impl std::fmt::Display) -> ApiError {
    ApiError(status, message.to_string())
}

fn internal(e: impl std::fmt::Display) -> ApiError {
    error(StatusCode::INTERNAL_SERVER_ERROR, e)
}

fn json_ok(value: serde_json::Value) -> Response {
    (
        [(header::CONTENT_TYPE, "application/json")],
        value.to_string(),
    )
        .into_response()
}

fn asset(name: &str) -> Response {
    match assets::get(name) {
        Some((mime, bytes)) => (
            [
                (header::CONTENT_TYPE, mime),
                (header::CACHE_CONTROL, "no-cache"),
            ],
            bytes,
        )
            .into_response(),
        None => error(StatusCode::NOT_FOUND, "no such asset").into_response(),
    }
}

async fn asset_route(axum::extract::Path(name): axum::extract::Path<String>) -> Response {
    asset(&name)
}

/// The admin behind the request, or the refusal as a response.
fn admin(c: &Console, headers: &HeaderMap) -> Result<String, ApiError> {
    admin_claims(c, headers).map(|claims| claims.player)
}

/// [`admin`]'s verified claims, for a stream that checks them again.
fn admin_claims(c: &Console, headers: &HeaderMap) -> Result<crate::auth::Claims, ApiError> {
    auth::admin(&c.ctx, headers).map_err(|r| error(r.status(), r))
}

async fn world(State(c): State<Arc<Console>>, headers: HeaderMap) -> ApiResult {
    let admin = admin(&c, &headers)?;
    let p = c.world.params();
    let rows = c.world.rows();
    Ok(json_ok(json!({
        "admin": admin,
        "seed": p.seed,
        "min_y": p.min_y,
        "max_y": p.max_y,
        "rows": [rows.start(), rows.end()],
        "tile_columns": TILE_COLUMNS,
        "tile_voxels": TILE_COLUMNS * strata_terrain::CHUNK_SIZE,
        "sample_ms": c.cfg.sample_ms,
        "scene_max_chunks": c.cfg.scene_max_chunks,
        "region_chunks": c.region_chunks,
        "clustered": c.world.store().clustered(),
        "node_id": c.node_id,
        "tiles_cached": c.tiles.len(),
        "watchers": c.hub.watchers(),
        "samples": c.hub.samples(),
    })))
}

/// Waits for a render slot, bounded.
async fn render_slot(c: &Console) -> Result<tokio::sync::OwnedSemaphorePermit, ApiError> {
    match tokio::time::timeout(RENDER_WAIT, c.renders.clone().acquire_owned()).await {
        Ok(Ok(p)) => Ok(p),
        _ => Err(error(
            StatusCode::SERVICE_UNAVAILABLE,
            "renderer busy; retry",
        )),
    }
}

fn bad(e: impl std::fmt::Display) -> ApiError {
    error(StatusCode::BAD_REQUEST, e)
}

fn tile_key(c: &Console, uri: &Uri) -> Result<TileKey, ApiError> {
    let q = Query::parse(uri.query(), &["view", "y", "tx", "tz", "v"]).map_err(bad)?;
    let lim = i64::from(MAX_TILE_COORD);
    let tx = q.int("tx", -lim, lim).map_err(bad)? as i32;
    let tz = q.int("tz", -lim, lim).map_err(bad)? as i32;
    let p = c.world.params();
    let view = match q.text("view").unwrap_or("top") {
        "top" => View::Top,
        "slice" => View::Slice(
            q.int("y", i64::from(p.min_y), i64::from(p.max_y))
                .map_err(bad)? as i32,
        ),
        _ => return Err(bad("view must be top or slice")),
    };
    Ok(TileKey { view, tx, tz })
}

async fn tile(State(c): State<Arc<Console>>, headers: HeaderMap, uri: Uri) -> ApiResult {
    admin(&c, &headers)?;
    let key = tile_key(&c, &uri)?;
    // The catch-up and the stamp on a blocking thread, one request at a
    // time; the work owns the turn, so a request given up on frees it
    // only when that work ends.
    let turn = c.catch_ups.clone().lock_owned().await;
    let c2 = c.clone();
    let stamp = tokio::task::spawn_blocking(move || {
        let _turn = turn;
        c2.versions.catch_up(c2.world.store().as_ref())?;
        let (x0, z0) = key.first_column();
        Ok::<_, crate::store::StoreError>(c2.versions.stamp(x0, z0, TILE_COLUMNS))
    })
    .await
    .map_err(internal)?
    .map_err(internal)?;
    let png = match c.tiles.get(&key, stamp) {
        Some(png) => png,
        None => {
            // The render owns its slot: `max_renders` bounds renders
            // running, not requests waiting on them.
            let slot = render_slot(&c).await?;
            let (world, pool) = (c.world.clone(), c.render_pool.clone());
            let png = tokio::task::spawn_blocking(move || {
                let _slot = slot;
                pool.install(|| tiles::render(&world, key))
            })
            .await
            .map_err(internal)?
            .map_err(internal)?;
            let png = Arc::new(png);
            c.tiles.put(key, stamp, png.clone());
            png
        }
    };
    Ok((
        [
            (header::CONTENT_TYPE, "image/png".to_string()),
            (header::CACHE_CONTROL, "no-store".to_string()),
            (header::ETAG, format!("\"{stamp}\"")),
        ],
        Body::from(png.as_ref().clone()),
    )
        .into_response())
}

fn scene_box(c: &Console, uri: &Uri) -> Result<(ChunkPos, ChunkPos), ApiError> {
    let keys = ["x0", "y0", "z0", "x1", "y1", "z1"];
    let q = Query::parse(uri.query(), &keys).map_err(bad)?;
    let lim = i64::from(MAX_TILE_COORD) * i64::from(TILE_COLUMNS);
    let rows = c.world.rows();
    let x = |n| q.int(n, -lim, lim).map(|v| v as i32).map_err(bad);
    let y = |n, d: i32| {
        q.int_opt(n, -lim, lim)
            .map(|v| v.map_or(d, |v| v as i32))
            .map_err(bad)
    };
    Ok((
        ChunkPos::new(x("x0")?, y("y0", *rows.start())?, x("z0")?),
        ChunkPos::new(x("x1")?, y("y1", *rows.end())?, x("z1")?),
    ))
}

async fn scene_glb(State(c): State<Arc<Console>>, headers: HeaderMap, uri: Uri) -> ApiResult {
    admin(&c, &headers)?;
    let (min, max) = scene_box(&c, &uri)?;
    let bx = scene::check_box(&c.world, min, max, c.cfg.scene_max_chunks).map_err(bad)?;
    let slot = render_slot(&c).await?;
    let (world, pool) = (c.world.clone(), c.render_pool.clone());
    let glb = tokio::task::spawn_blocking(move || {
        let _slot = slot;
        pool.install(|| scene::build(&world, bx))
    })
    .await
    .map_err(internal)?
    .map_err(|e| {
        if e.is_bad_request() {
            bad(e)
        } else {
            internal(e)
        }
    })?;
    Ok((
        [
            (header::CONTENT_TYPE, "model/gltf-binary"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        glb,
    )
        .into_response())
}

async fn regions_route(State(c): State<Arc<Console>>, headers: HeaderMap, uri: Uri) -> ApiResult {
    admin(&c, &headers)?;
    let q = Query::parse(uri.query(), &["x0", "z0", "x1", "z1"]).map_err(bad)?;
    let lim = i64::from(MAX_TILE_COORD) * i64::from(TILE_COLUMNS);
    let x = |n| q.int(n, -lim, lim).map(|v| v as i32).map_err(bad);
    let (from, to) = ((x("x0")?, x("z0")?), (x("x1")?, x("z1")?));
    let c2 = c.clone();
    let (side, max) = (c.region_chunks, c.cfg.regions_per_request);
    let answer = tokio::task::spawn_blocking(move || {
        regions::holders(c2.world.store().as_ref(), side, (from, to), max)
    })
    .await
    .map_err(internal)?;
    match answer {
        Ok(v) => Ok(json_ok(v)),
        Err(e @ regions::RegionsError::Store(_)) => Err(internal(e)),
        Err(e) => Err(bad(e)),
    }
}

async fn events(State(c): State<Arc<Console>>, headers: HeaderMap) -> ApiResult {
    let claims = admin_claims(&c, &headers)?;
    let admin = claims.player.clone();
    let stream = c
        .hub
        .subscribe(
            (c.cfg.max_watchers, c.cfg.event_queue),
            c.ctx.clone(),
            claims,
        )
        .ok_or_else(|| {
            error(
                StatusCode::SERVICE_UNAVAILABLE,
                "too many watching consoles ([console] max_watchers)",
            )
        })?;
    info!(%admin, "console watcher connected");
    Ok(Sse::new(stream)
        .keep_alive(KeepAlive::new().interval(c.cfg.keep_alive()))
        .into_response())
}

async fn action(State(c): State<Arc<Console>>, req: Request) -> ApiResult {
    if req.method() != Method::POST {
        return Err(error(StatusCode::METHOD_NOT_ALLOWED, "POST only"));
    }
    let claims = admin_claims(&c, req.headers())?;
    let body = axum::body::to_bytes(req.into_body(), c.cfg.max_body_bytes)
        .await
        .map_err(|_| {
            error(
                StatusCode::PAYLOAD_TOO_LARGE,
                format!("the body is over {} bytes", c.cfg.max_body_bytes),
            )
        })?;
    let request: ActionRequest =
        serde_json::from_slice(&body).map_err(|e| bad(format!("bad action: {e}")))?;
    match actions::run(&c, &claims, request).await {
        Ok(v) => Ok(json_ok(json!({ "ok": v }))),
        Err(e @ ActionError::NotConfirmed) => Err(bad(e)),
        Err(e @ ActionError::Refused(_)) => Err(error(StatusCode::CONFLICT, e)),
        Err(e @ ActionError::Unavailable(_)) => Err(error(StatusCode::SERVICE_UNAVAILABLE, e)),
    }
}
