/*
 * A game's first steps with libstrata, in C: connect, find the ground by
 * reading chunks, stand on it, dig, see our own delta arrive, mesh the
 * chunk. Prints one "key=value ..." line per step and exits 0 on success.
 *
 *   strata_example ADDRESS CERT_DER_FILE TOKEN
 *
 * Build: cc main.c -I sdk/include -L <dir of libstrata> -lstrata
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "strata.h"

#define COLUMN_OFFSET 3   /* voxels from the spawn column, inside the spawn area */
#define WAIT_MS 10000     /* the longest this example waits for anything */

static void sleep_ms(long ms) {
    struct timespec t = {ms / 1000, (ms % 1000) * 1000000L};
    nanosleep(&t, NULL);
}

static int fail(const char *what, StrataStatus st) {
    fprintf(stderr, "error %s: status %d: %s\n", what, (int)st, strata_last_error_message());
    return 1;
}

static unsigned char *read_file(const char *path, size_t *len) {
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    unsigned char *buf = malloc(n > 0 ? (size_t)n : 1);
    *len = fread(buf, 1, (size_t)n, f);
    fclose(f);
    return buf;
}

/* Drains events; returns the verdict event of `ticket` once it comes. */
static int wait_verdict(StrataSession *s, uint64_t ticket, StrataEvent *verdict) {
    for (int waited = 0; waited < WAIT_MS; waited += 5) {
        StrataEvent ev;
        StrataStatus st = strata_poll(s, &ev);
        if (st != STRATA_STATUS_OK) return fail("poll", st);
        if (ev.kind == STRATA_EVENT_KIND_NONE) { sleep_ms(5); continue; }
        if (ev.kind == STRATA_EVENT_KIND_DISCONNECTED) {
            fprintf(stderr, "disconnected: %s\n", ev.message);
            return 1;
        }
        if (ev.ticket == ticket && (ev.kind == STRATA_EVENT_KIND_EDIT_ACCEPTED ||
                                    ev.kind == STRATA_EVENT_KIND_EDIT_REJECTED ||
                                    ev.kind == STRATA_EVENT_KIND_EDIT_FAILED)) {
            *verdict = ev;
            return 0;
        }
    }
    fprintf(stderr, "no verdict for edit %llu\n", (unsigned long long)ticket);
    return 1;
}

int main(int argc, char **argv) {
    if (argc != 4) {
        fprintf(stderr, "usage: %s ADDRESS CERT_DER_FILE TOKEN\n", argv[0]);
        return 2;
    }
    /* A library built from another header must not be called. */
    if (strata_abi_version() != STRATA_ABI_VERSION) {
        fprintf(stderr, "libstrata ABI %u, this program's %u\n",
                strata_abi_version(), (unsigned)STRATA_ABI_VERSION);
        return 2;
    }
    size_t cert_len = 0;
    unsigned char *cert = read_file(argv[2], &cert_len);
    if (!cert) { perror(argv[2]); return 2; }

    /* Zeroed, then sized: options a later library adds read as 0. */
    StrataConnectOptions options;
    memset(&options, 0, sizeof options);
    options.size = sizeof options;
    options.predict = 0;
    StrataSession *s = NULL;
    StrataStatus st = strata_connect_with(argv[1], cert, cert_len, argv[3], &options, &s);
    free(cert);
    if (st != STRATA_STATUS_OK) return fail("connect", st);
    StrataWelcome w;
    if ((st = strata_welcome(s, &w)) != STRATA_STATUS_OK) return fail("welcome", st);
    printf("connected session=%llu view_radius=%u\n", (unsigned long long)w.session, w.view_radius);

    /* The column to stand in, and the chunks around it. */
    int x = w.spawn_x + COLUMN_OFFSET, z = w.spawn_z + COLUMN_OFFSET;
    int32_t c[3];
    strata_chunk_of(x, 0, z, c);
    if ((st = strata_subscribe(s, c[0], 1, c[2], w.view_radius)) != STRATA_STATUS_OK)
        return fail("subscribe", st);

    /* Wait until the column's chunks (y -1 ..= 3) are held, then find the ground. */
    static uint8_t density[STRATA_CHUNK_VOLUME];
    int ground = 0, found = 0, lx = x & 31, lz = z & 31;
    for (int waited = 0; !found && waited < WAIT_MS; waited += 10) {
        StrataEvent ev;
        while (strata_poll(s, &ev) == STRATA_STATUS_OK && ev.kind != STRATA_EVENT_KIND_NONE) {}
        int held = 1;
        for (int cy = 3; cy >= -1 && held && !found; cy--) {
            st = strata_chunk_read(s, c[0], cy, c[2], density, NULL, sizeof density, NULL);
            if (st == STRATA_STATUS_NOT_HELD) { held = 0; break; }
            if (st != STRATA_STATUS_OK) return fail("chunk_read", st);
            for (int ly = 31; ly >= 0; ly--) {
                if (density[lx + 32 * (ly + 32 * lz)] >= 128) {
                    ground = cy * 32 + ly;
                    found = 1;
                    break;
                }
            }
        }
        if (!found) sleep_ms(10);
    }
    if (!found) { fprintf(stderr, "the column never arrived\n"); return 1; }
    printf("ground x=%d y=%d z=%d\n", x, ground, z);

    /* Stand on it and dig below our feet; a position is a datagram, so
     * an edit that arrives first is refused with NO_POSITION: send again. */
    double feet[3] = {x + 0.5, ground + 1.0, z + 0.5};
    StrataEdit dig = {0};
    dig.kind = STRATA_EDIT_KIND_MINE;
    dig.center[0] = x + 0.5; dig.center[1] = ground + 0.5; dig.center[2] = z + 0.5;
    dig.radius = 2.0;
    dig.strength = 255;
    StrataEvent verdict;
    uint64_t ticket = 0;
    for (int attempt = 0; attempt < 50; attempt++) {
        if ((st = strata_set_position(s, feet[0], feet[1], feet[2])) != STRATA_STATUS_OK)
            return fail("set_position", st);
        sleep_ms(20);
        if ((st = strata_edit(s, &dig, &ticket)) != STRATA_STATUS_OK) return fail("edit", st);
        if (wait_verdict(s, ticket, &verdict)) return 1;
        if (verdict.kind != STRATA_EVENT_KIND_EDIT_REJECTED ||
            verdict.reject != STRATA_REJECT_NO_POSITION) break;
    }
    if (verdict.kind != STRATA_EVENT_KIND_EDIT_ACCEPTED) {
        fprintf(stderr, "edit not accepted: %s\n", verdict.message);
        return 1;
    }
    printf("accepted ticket=%llu seq=%llu chunks=%zu\n", (unsigned long long)ticket,
           (unsigned long long)verdict.seq, verdict.changes_len);
    if (verdict.changes_len == 0) { fprintf(stderr, "the edit changed nothing\n"); return 1; }
    StrataChunkVersion changed = verdict.changes[0]; /* valid until the next poll: copy it */

    /* Our own delta: the replica reaches the version the server gave. */
    uint64_t version = 0;
    for (int waited = 0; version < changed.version && waited < WAIT_MS; waited += 5) {
        StrataEvent ev;
        while (strata_poll(s, &ev) == STRATA_STATUS_OK && ev.kind != STRATA_EVENT_KIND_NONE) {}
        st = strata_chunk_read(s, changed.chunk[0], changed.chunk[1], changed.chunk[2], NULL,
                               NULL, 0, &version);
        if (st != STRATA_STATUS_OK && st != STRATA_STATUS_NOT_HELD) return fail("chunk_read", st);
        if (version < changed.version) sleep_ms(5);
    }
    if (version < changed.version) { fprintf(stderr, "our delta never came\n"); return 1; }
    printf("delta chunk=%d,%d,%d version=%llu\n", changed.chunk[0], changed.chunk[1],
           changed.chunk[2], (unsigned long long)version);

    /* Mesh it at full detail, and at LOD 1 with transition cells on every face. */
    const uint8_t lods[2] = {0, 1}, faces[2] = {0, 0x3f};
    for (int i = 0; i < 2; i++) {
        StrataMesh *m = NULL;
        st = strata_mesh(s, changed.chunk[0], changed.chunk[1], changed.chunk[2], lods[i], faces[i], &m);
        if (st != STRATA_STATUS_OK) return fail("mesh", st);
        StrataMeshData d;
        if ((st = strata_mesh_data(m, &d)) != STRATA_STATUS_OK) return fail("mesh_data", st);
        printf("mesh lod=%u faces=%u vertices=%zu triangles=%zu complete=%d hash=%016llx\n",
               d.lod, faces[i], d.vertex_count, d.index_count / 3, d.complete ? 1 : 0,
               (unsigned long long)d.hash);
        strata_mesh_free(m);
    }

    /* The library re-meshes changed chunks itself and compares hashes with
     * the server's at each tick's end. */
    StrataStats stats;
    for (int waited = 0; waited < WAIT_MS; waited += 10) {
        if ((st = strata_stats(s, &stats)) != STRATA_STATUS_OK) return fail("stats", st);
        if (stats.meshes_checked > 0) break;
        StrataEvent ev;
        while (strata_poll(s, &ev) == STRATA_STATUS_OK && ev.kind != STRATA_EVENT_KIND_NONE) {}
        sleep_ms(10);
    }
    printf("stats chunks=%llu deltas=%llu meshes_checked=%llu mesh_mismatches=%llu\n",
           (unsigned long long)stats.chunks_held, (unsigned long long)stats.deltas,
           (unsigned long long)stats.meshes_checked, (unsigned long long)stats.mesh_mismatches);

    /* Errors are codes plus a message. */
    StrataMesh *bad = NULL;
    st = strata_mesh(s, changed.chunk[0], changed.chunk[1], changed.chunk[2], 9, 0, &bad);
    printf("error status=%d message=%s\n", (int)st, strata_last_error_message());

    strata_session_free(s);
    printf("bye\n");
    return 0;
}
