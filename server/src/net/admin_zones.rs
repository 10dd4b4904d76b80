//! Protected zones changed by admin sessions (and the console): each change
//! is made to the stored zones (`stored_zones.rs`, shared by a cluster's
//! nodes) off the engine thread, then handed to the engine whole. Every
//! [`ZONES_RELOAD_PERIOD`] the stored zones are read again, so changes made
//! on another node apply here too.

use std::sync::Arc;

use strata_protocol::admin::{AdminResponse, ZoneSpec};
use tracing::{info, warn};

use super::admin_session::ask;
use super::session::SessionContext;
use crate::engine::admin::{zone_spec, AdminCommand};
use crate::health::StoreWork;
use crate::shutdown::Shutdown;
use crate::stored_zones::{self, ZoneChange, ZonesError, ZONES_RELOAD_PERIOD};
use crate::validate::zones::Zone;

/// Makes `change` to the stored zones, durably, then to the engine's.
/// One change at a time on this node (`zone_writes`); a refused or failed
/// change leaves both as they were.
pub(crate) async fn answer(
    ctx: &Arc<SessionContext>,
    change: ZoneChange,
) -> Result<AdminResponse, String> {
    let _one_writer = ctx.zone_writes.lock().await;
    let store = ctx.store.clone();
    let defaults = ctx.default_zones.clone();
    let written =
        tokio::task::spawn_blocking(move || stored_zones::change(&*store, &defaults, &change))
            .await
            .map_err(|e| e.to_string())?;
    match written {
        Ok(zones) => Ok(AdminResponse::Zones(install(ctx, zones).await?)),
        Err(e @ ZonesError::Store(_)) => Ok(AdminResponse::Refused {
            message: format!("zones not saved: {e}"),
        }),
        Err(e) => Ok(AdminResponse::Refused {
            message: e.to_string(),
        }),
    }
}

/// Hands `zones` to the engine; returns them as it holds them now.
async fn install(ctx: &SessionContext, zones: Vec<Zone>) -> Result<Vec<ZoneSpec>, String> {
    ask(ctx, |reply| AdminCommand::SetZones { zones, reply }).await
}

/// Reads the stored zones every [`ZONES_RELOAD_PERIOD`] and hands them to
/// the engine when they differ from its own, until shutdown. A failed read
/// (or none stored) keeps the engine's.
pub async fn reload(ctx: Arc<SessionContext>, mut shutdown: Shutdown) {
    ctx.health
        .expect_every(StoreWork::Zones, ZONES_RELOAD_PERIOD);
    let start = tokio::time::Instant::now() + ZONES_RELOAD_PERIOD;
    let mut tick = tokio::time::interval_at(start, ZONES_RELOAD_PERIOD);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            _ = shutdown.wait() => return,
        }
        let _one_writer = ctx.zone_writes.lock().await;
        let store = ctx.store.clone();
        let read = tokio::task::spawn_blocking(move || stored_zones::stored(&*store)).await;
        // The store answered (zones that do not parse are the data's fault).
        match &read {
            Ok(Err(ZonesError::Store(e))) => ctx.health.store_error(StoreWork::Zones, e),
            Ok(_) => ctx.health.store_ok(StoreWork::Zones),
            Err(_) => {}
        }
        let stored = match read {
            Ok(Ok(Some(zones))) => zones,
            Ok(Ok(None)) => continue,
            Ok(Err(e)) => {
                warn!(error = %e, "reloading the protected zones failed");
                continue;
            }
            Err(e) => {
                warn!(error = %e, "reloading the protected zones failed");
                continue;
            }
        };
        let held = match ask(&ctx, AdminCommand::Zones).await {
            Ok(z) => z,
            Err(e) => {
                warn!(error = %e, "reloading the protected zones failed");
                continue;
            }
        };
        let specs: Vec<ZoneSpec> = stored.iter().map(zone_spec).collect();
        if specs != held {
            info!(
                zones = specs.len(),
                "protected zones changed elsewhere: adopted"
            );
            if let Err(e) = install(&ctx, stored).await {
                warn!(error = %e, "reloading the protected zones failed");
            }
        }
    }
}
