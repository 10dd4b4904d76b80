"""A game's first steps with libstrata from Python (ctypes): connect, find
the ground by reading chunks, stand on it, dig, see our own delta arrive,
mesh the chunk. Prints one "key=value ..." line per step; exits 0 on success.

    python3 strata_example.py LIBSTRATA ADDRESS CERT_DER_FILE TOKEN

The structs below mirror sdk/include/strata.h.
"""

import ctypes as C
import sys
import time

CHUNK_VOLUME = 32 * 32 * 32
WAIT_S = 10.0
COLUMN_OFFSET = 3

OK, NOT_HELD = 0, 9
EV_NONE, EV_ACCEPTED, EV_REJECTED, EV_FAILED, EV_CHUNK, EV_DISCONNECTED = range(6)
REJECT_NO_POSITION = 10
EDIT_MINE = 0


class ChunkVersion(C.Structure):
    _fields_ = [("chunk", C.c_int32 * 3), ("version", C.c_uint64)]


class Event(C.Structure):
    _fields_ = [
        ("kind", C.c_int),
        ("ticket", C.c_uint64),
        ("seq", C.c_uint64),
        ("changes", C.POINTER(ChunkVersion)),
        ("changes_len", C.c_size_t),
        ("reject", C.c_int),
        ("chunk", C.c_int32 * 3),
        ("error_code", C.c_uint32),
        ("message", C.c_char * 256),
        ("position_refusal", C.c_int),
        ("radius", C.c_uint8),
        ("held", C.c_double * 3),
        ("held_known", C.c_uint8),
    ]


class Edit(C.Structure):
    _fields_ = [
        ("kind", C.c_uint32),
        ("center", C.c_double * 3),
        ("radius", C.c_double),
        ("strength", C.c_uint8),
        ("power", C.c_uint16),
        ("material", C.c_uint8),
        ("min", C.c_int32 * 3),
        ("max", C.c_int32 * 3),
        ("structure", C.c_uint32),
        ("rotation", C.c_uint8),
    ]


class Welcome(C.Structure):
    _fields_ = [
        ("session", C.c_uint64),
        ("world_seed", C.c_uint64),
        ("last_seq", C.c_uint64),
        ("view_radius", C.c_uint8),
        ("resume", C.c_uint8),
        ("resume_feet", C.c_double * 3),
        ("spawn_x", C.c_int32),
        ("spawn_z", C.c_int32),
        ("spawn_radius", C.c_uint32),
    ]


class MeshData(C.Structure):
    _fields_ = [
        ("positions", C.POINTER(C.c_float)),
        ("normals", C.POINTER(C.c_float)),
        ("materials", C.POINTER(C.c_uint8)),
        ("indices", C.POINTER(C.c_uint32)),
        ("vertex_count", C.c_size_t),
        ("index_count", C.c_size_t),
        ("origin", C.c_int32 * 3),
        ("lod", C.c_uint8),
        ("complete", C.c_uint8),
        ("hash", C.c_uint64),
    ]


# STRATA_ABI_VERSION of the header this mirror follows.
ABI_VERSION = 2


class Strata:
    """The library, with a check on every call's status."""

    def __init__(self, path):
        self.lib = C.CDLL(path)
        self.lib.strata_last_error_message.restype = C.c_char_p
        self.lib.strata_set_position.argtypes = [C.c_void_p, C.c_double, C.c_double, C.c_double]
        self.lib.strata_chunk_of.argtypes = [C.c_double, C.c_double, C.c_double, C.POINTER(C.c_int32)]
        self.lib.strata_event_size.restype = C.c_size_t
        self.lib.strata_abi_version.restype = C.c_uint32
        # This mirror follows the header's STRATA_ABI_VERSION.
        if self.lib.strata_abi_version() != ABI_VERSION:
            raise RuntimeError(
                f"libstrata ABI {self.lib.strata_abi_version()}, this mirror's {ABI_VERSION}"
            )
        # strata_poll writes the library's whole StrataEvent into ours.
        if self.lib.strata_event_size() != C.sizeof(Event):
            raise RuntimeError(
                f"StrataEvent is {self.lib.strata_event_size()} bytes in the library, "
                f"{C.sizeof(Event)} here: update this mirror"
            )

    def call(self, name, *args, allow=(OK,)):
        status = getattr(self.lib, name)(*args)
        if status not in allow:
            message = self.lib.strata_last_error_message().decode()
            raise RuntimeError(f"{name}: status {status}: {message}")
        return status

    def drain(self, s):
        """Polls until no event is left; returns (event, changes) pairs."""
        events = []
        while True:
            ev = Event()
            self.call("strata_poll", s, C.byref(ev))
            # ev.changes lives until the next poll: copy them now.
            changes = [(tuple(ev.changes[i].chunk), ev.changes[i].version)
                       for i in range(ev.changes_len)]
            if ev.kind == EV_NONE:
                return events
            if ev.kind == EV_DISCONNECTED:
                raise RuntimeError(f"disconnected: {ev.message.decode()}")
            events.append((ev, changes))


def main():
    if len(sys.argv) != 5:
        sys.exit(f"usage: {sys.argv[0]} LIBSTRATA ADDRESS CERT_DER_FILE TOKEN")
    lib_path, address, cert_path, token = sys.argv[1:]
    st = Strata(lib_path)
    cert = open(cert_path, "rb").read()

    s = C.c_void_p()
    st.call("strata_connect", address.encode(), cert, C.c_size_t(len(cert)), token.encode(),
            C.c_uint8(0), C.byref(s))
    w = Welcome()
    st.call("strata_welcome", s, C.byref(w))
    print(f"connected session={w.session} view_radius={w.view_radius}")

    x, z = w.spawn_x + COLUMN_OFFSET, w.spawn_z + COLUMN_OFFSET
    c = (C.c_int32 * 3)()
    st.call("strata_chunk_of", float(x), 0.0, float(z), c)
    st.call("strata_subscribe", s, c[0], 1, c[2], C.c_uint8(w.view_radius))

    # The ground: the highest solid voxel of the column, once its chunks are held.
    density = (C.c_uint8 * CHUNK_VOLUME)()
    lx, lz = x & 31, z & 31
    ground = None
    deadline = time.monotonic() + WAIT_S
    while ground is None and time.monotonic() < deadline:
        st.drain(s)
        for cy in range(3, -2, -1):
            if st.call("strata_chunk_read", s, c[0], cy, c[2], density, None,
                       C.c_size_t(CHUNK_VOLUME), None, allow=(OK, NOT_HELD)) == NOT_HELD:
                break
            solid = [ly for ly in range(31, -1, -1) if density[lx + 32 * (ly + 32 * lz)] >= 128]
            if solid:
                ground = cy * 32 + solid[0]
                break
        else:
            continue
        time.sleep(0.01)
    if ground is None:
        sys.exit("the column never arrived")
    print(f"ground x={x} y={ground} z={z}")

    dig = Edit(kind=EDIT_MINE, radius=2.0, strength=255)
    dig.center[:] = [x + 0.5, ground + 0.5, z + 0.5]
    ticket = C.c_uint64()
    verdict = None
    for _ in range(50):
        st.call("strata_set_position", s, x + 0.5, ground + 1.0, z + 0.5)
        time.sleep(0.02)
        st.call("strata_edit", s, C.byref(dig), C.byref(ticket))
        deadline = time.monotonic() + WAIT_S
        verdict = None
        while verdict is None and time.monotonic() < deadline:
            for ev, changes in st.drain(s):
                if ev.ticket == ticket.value and ev.kind in (EV_ACCEPTED, EV_REJECTED, EV_FAILED):
                    verdict = (ev.kind, ev.reject, ev.seq, changes, ev.message.decode())
                    break
            time.sleep(0.005)
        if verdict is None:
            sys.exit("no verdict")
        if not (verdict[0] == EV_REJECTED and verdict[1] == REJECT_NO_POSITION):
            break
    kind, _, seq, changes, message = verdict
    if kind != EV_ACCEPTED or not changes:
        sys.exit(f"edit not accepted or changed nothing: {message}")
    print(f"accepted ticket={ticket.value} seq={seq} chunks={len(changes)}")

    (cx, cy, cz), want = changes[0]
    version = C.c_uint64(0)
    deadline = time.monotonic() + WAIT_S
    while version.value < want and time.monotonic() < deadline:
        st.drain(s)
        st.call("strata_chunk_read", s, cx, cy, cz, None, None, C.c_size_t(0),
                C.byref(version), allow=(OK, NOT_HELD))
        time.sleep(0.005)
    if version.value < want:
        sys.exit("our delta never came")
    print(f"delta chunk={cx},{cy},{cz} version={version.value}")

    for lod, faces in ((0, 0), (1, 0x3F)):
        m = C.c_void_p()
        st.call("strata_mesh", s, cx, cy, cz, C.c_uint8(lod), C.c_uint8(faces), C.byref(m))
        d = MeshData()
        st.call("strata_mesh_data", m, C.byref(d))
        # The arrays are flat: three floats per vertex.
        top = max(d.positions[3 * i + 1] for i in range(d.vertex_count)) if d.vertex_count else 0
        print(f"mesh lod={d.lod} faces={faces} vertices={d.vertex_count} "
              f"triangles={d.index_count // 3} complete={int(d.complete)} hash={d.hash:016x} "
              f"top_y={top:.2f}")
        st.lib.strata_mesh_free(m)

    st.lib.strata_session_free(s)
    print("bye")


if __name__ == "__main__":
    main()
