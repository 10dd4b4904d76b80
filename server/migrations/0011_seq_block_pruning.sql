-- How far the edit log was pruned ([store] log_retention) in each seq
-- block: a cluster's nodes number from blocks 2^40 apart, so each block's
-- log is pruned from its own start (world.log_base keeps the seqs before
-- the first block). `check` lets the log jump to pruned_to + 1.
ALTER TABLE seq_blocks ADD COLUMN pruned_to bigint NOT NULL DEFAULT 0 CHECK (pruned_to >= 0);
