-- Region leases (server/src/store/pg/lease.rs): which node may write which
-- region. A row appears when a region is first claimed. owner is NULL once
-- released; epoch rises by one at every claim, never otherwise, and every
-- commit checks the epoch its node holds for each region it writes.
-- lease_expires is on the database's clock, so nodes' clocks may differ.
CREATE TABLE regions (
    region_x      integer     NOT NULL,
    region_z      integer     NOT NULL,
    owner         text,
    epoch         bigint      NOT NULL CHECK (epoch > 0),
    lease_expires timestamptz NOT NULL,
    PRIMARY KEY (region_x, region_z)
);
CREATE INDEX regions_by_owner ON regions (owner);
