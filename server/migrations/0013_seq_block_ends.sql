-- Each seq block's last seq: blocks are no longer all 2^40 seqs
-- ([cluster] seq_block), so readers of the log (a node's newest block is a
-- segment being written) read each one's end here. Blocks reserved before
-- were 2^40 long.
ALTER TABLE seq_blocks ADD COLUMN last_seq bigint;
UPDATE seq_blocks SET last_seq = first_seq + 1099511627775;
ALTER TABLE seq_blocks ALTER COLUMN last_seq SET NOT NULL;
ALTER TABLE seq_blocks ADD CONSTRAINT seq_blocks_last_seq CHECK (last_seq >= first_seq);
-- Each node's newest block, found by an index probe per node, and the
-- blocks reserved lately (a reader starting at the log's end): nodes
-- trading regions reserve a block at each handoff, so the table grows.
CREATE INDEX seq_blocks_node ON seq_blocks (node, first_seq);
CREATE INDEX seq_blocks_reserved_at ON seq_blocks (reserved_at);
