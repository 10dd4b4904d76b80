-- What `strata-admin cluster status` reports per region (store/pg/lease.rs,
-- store/pg/fence.rs): when the lease was last claimed or renewed, and how
-- many accepted edits changed the region. `edits` rises inside each fenced
-- commit transaction, so a rolled-back (fenced) commit counts nothing.
ALTER TABLE regions ADD COLUMN renewed_at timestamptz NOT NULL DEFAULT now();
ALTER TABLE regions ADD COLUMN edits bigint NOT NULL DEFAULT 0 CHECK (edits >= 0);
