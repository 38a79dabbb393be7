"""The wire format: how request bodies become arrays, and answers become bodies.

This docstring is the spec of every body the service reads and writes; API.md is the contract it
implements. Everything here is plain NumPy (mesh files are read by ``meshfile``), so the
client uses the same code to write requests and read answers. One module per job: ``formats``
(which format a body is in), ``body`` (buffering), ``npy``, ``npz_reader``, ``npz_writer`` and
``zip_records`` (the files), ``meshfile`` (mesh files), ``arrays`` (dtype and shape rules),
``decoders`` (request bodies) and ``answers`` (content negotiation and answer bodies).

Body formats
------------
The format of a body is chosen by ``?format=`` if given, else by ``Content-Type``:

=========  ==============================================  =========================================
format     Content-Type                                    read with
=========  ==============================================  =========================================
``npy``    ``application/x-npy`` (or ``application/npy``)  a header parse, then ``np.frombuffer``
``npz``    ``application/x-npz`` (``application/npz``,     ``zipfile``; stored members are viewed in
           ``application/zip``)                            place, deflated ones decompressed once
``json``   ``application/json``                            ``json.loads``
``obj``    ``model/obj``                                   ``meshfile`` (NumPy)
``ply``    ``application/ply`` (``model/ply``)             ``meshfile``: NumPy (ASCII), trimesh
``stl``    ``model/stl`` (``application/sla``)             ``meshfile``: trimesh (binary or ASCII)
``glb``    ``model/gltf-binary``                           ``meshfile``: trimesh
``off``    ``model/off`` (``application/off``)             ``meshfile`` (NumPy)
=========  ==============================================  =========================================

``?format=`` names the format where the ``Content-Type`` does not, but never against it: a
``Content-Type`` of another format, or one that pages of any site may send (``text/plain``, form
and multipart bodies) for an npy, npz or JSON body, is 415; ``text/plain`` may hold a text mesh
file. With no ``Content-Type`` or ``application/octet-stream`` the format is sniffed from the
first bytes (``\\x93NUMPY`` npy, ``PK`` npz, ``glTF`` glb, ``ply`` ply, ``OFF`` off, ``{`` json);
anything else is 415, as is a known format the endpoint does not read.

Binary arrays must be little-endian with exactly the dtype below; a wrong dtype or shape is 422
with the fix in the message (the binary path never converts behind the caller's back: that would
be a hidden copy). ``allow_pickle`` is never on: an object array is 422 and is never unpickled.
A ``.npy`` body whose data is shorter or longer than its header says, or whose shape has a
negative length, is 400; a structured, subarray or void dtype is 422. An ``.npz`` whose members
add up to more than ``max_bytes`` once decompressed is 413; its members must be stored or
deflated, unencrypted, each named once, and must not overlap (400 otherwise), at most
``MAX_NPZ_MEMBERS`` of them. A deflated member is inflated piece by piece and refused as soon as
it passes its declared size, so no body costs more than the limit in memory.

JSON values are read as JSON types: numbers where numbers are expected (a string such as
``"0.5"`` or a boolean is 422), JSON nested too deeply for the parser is 400, and an integer of
more digits than Python converts (4300) is 422 naming where it is (``body's width``).

Rays (``decode_rays``; formats npy, npz, json)
    npy  float32 (N, 6) ``[ox, oy, oz, dx, dy, dz]`` or (N, 8) ``[..., tmin, tmax]``.
    npz  ``origins`` float32 (N, 3), ``directions`` float32 (N, 3); optional ``tmin``, ``tmax``
         float32 of shape (N,) or () (one value for the batch); optional ``mask`` uint32 of
         shape (N,) or (); optional ``time`` float32 (N,) or () in [0, 1], each ray's instant
         in the frame's interval (API.md "Motion"). No other keys.
    json ``{"origins": [[x, y, z], ...], "directions": [...], "tmin": number | [..] | null,
         "tmax": number | [..] | null, "mask": integer | [..] | null, "time": number | [..] |
         null}``; a null field means the
         default, a null element of tmin or tmax +inf; mask values are decimal integers in
         [0, 2**32).
    Defaults: tmin 0, tmax +inf, mask 0xFFFFFFFF, time 0. An npy body has no mask (nor time):
    the query string's ``?mask=`` gives one mask to a batch of any format (with a body mask too,
    422). More than
    ``max_rays`` rays is 413. Values (finite, non-zero directions, tmin <= tmax) are checked by the
    engine, which names the first bad ray (or time).

Points (``decode_points``; formats npy, npz, json)
    npy  float32 (N, 3) ``[x, y, z]``.
    npz  ``points`` float32 (N, 3). No other keys.
    json ``{"points": [[x, y, z], ...]}``.
    More than ``max_points`` points is 413. Values (finite) are checked by the engine, which
    names the first bad point.

Meshes (``decode_mesh``; formats npz, json, obj, ply, stl, glb, off)
    npz  ``vertices`` float32 (V, 3) and ``faces`` int32 or uint32 (F, 3). No other keys.
    json ``{"vertices": [[x, y, z], ...], "faces": [[i, j, k], ...]}`` (faces must be integers).
    A mesh file gives its geometry only, never decoding textures or materials; vertices and
    winding are as in the file; all its objects are merged into one mesh with their scene
    transforms applied; a file with no triangles is 400 (``meshfile`` states the rules). Every
    vertex must be finite and every face index in ``[0, V)``: otherwise 422 naming the first bad
    row (for OBJ and OFF, the line) and how many there are.

Vertices (``decode_vertices``; formats npy, npz, json)
    npy float32 (V, 3); npz key ``vertices``; json ``{"vertices": [[x, y, z], ...]}``.

Frames (``decode_frame``; formats npz, json)
    Keys ``MESH.vertices`` and optionally ``MESH.faces`` for any number of meshes (a mesh name may
    itself contain dots: the suffix after the last dot is the part). JSON uses the same flat keys.
    Each mesh may also have ``MESH.transform``: a (4, 4) row-major affine matrix (npz: float32 or
    float64; JSON: 4 lists of 4 numbers), checked by the engine (``check_matrix``);
    ``MESH.mask``: a uint32 (npz: an integer array of one element; JSON: an integer or a string
    in decimal or ``0x`` hex, ``parse_mask``); ``MESH.reflectivity`` (a number in [0, 1]) and
    ``MESH.label`` (an integer in [0, 2**32)), as JSON numbers or npz arrays of one element;
    ``MESH.transform_end``: its placement at the end of the frame's interval (as
    ``MESH.transform``; a frame that gives a mesh ``MESH.transform`` and no
    ``MESH.transform_end`` makes it static again); ``MESH.vertices_end``: its vertices at the
    end of the interval (as ``MESH.vertices``, as many; on a mesh with no transform; a frame
    that gives a mesh ``MESH.vertices`` and no ``MESH.vertices_end`` makes it static again);
    and, in JSON only, ``MESH.instance_of``: the
    name of the mesh whose arrays it shares, never with ``MESH.vertices`` or ``MESH.faces``.

Scan patterns (``decode_pattern``; formats npz, json)
    ``azimuth_deg`` and ``elevation_deg`` (M,), optional ``time_s`` (M,) and ``channel`` (M,)
    integers (npz: uint16); no other keys. More than ``max_rays`` rays is 413; values are checked
    by the engine's ``dacrt.sensors.Pattern``, which names the key and the first bad row.

One-shot trace (``decode_trace``; formats npz, json)
    The keys of a mesh (``vertices``, ``faces``) and of rays (``origins``, ``directions``,
    ``tmin``, ``tmax``, ``mask``, ``time``) in one body.

Answers (``negotiate`` and ``encode_answer``)
    ``Accept`` picks ``application/x-npz``, ``application/x-npy`` or ``application/json`` (q-values
    honoured); absent, ``*/*`` or ``application/*`` gives JSON for a JSON request and npz for any
    other; naming none of these is 406. A type's q is that of the most specific range naming it
    (``type/sub``, then ``type/*``, then ``*/*``), so ``application/json;q=0, */*`` refuses JSON.
    npz  one uncompressed member per field (``t``, ``mesh``, ...); the body is sent as zip headers
         around the answer arrays' own memory, never joined into one copy.
    npy  a single field is a plain array; several fields are one structured array with a named
         field each (``a["t"]``, ``a["normal"]`` of shape (N, 3)). So every field must have one
         row per ray: a hits answer in CSR form (``offsets`` and per-hit keys) is npz or JSON only
         (the route's ``formats`` for ``negotiate``).
    pcd  a lidar's points only (``Accept: application/x-pcd``): a binary PCD v0.7 file of the
         fields asked, in the order asked (``x y z`` for ``xyz``), ``dacrt.sensors.pcd``.
    json ``{"t": [...], ...}``; float32 values in their shortest round-trip form, so
         ``np.float32(json_value)`` gives back the binary answer bit for bit; inf (and nan) are
         null. A rig's answer is ``{"NAME": {"KEY": [...], ...}, ...}`` (npz: keys ``NAME.KEY``).
         A query-string bound that takes such a value back (``?max_distance=``) reads a
         float32's shortest decimal as that float32 (``float32_if_shortest``).
"""

from .answers import (
    check_accepts,
    encode_answer,
    encode_json,
    encode_rig_answer,
    json_ready,
    negotiate,
    npy_parts,
)
from .arrays import (
    MeshArrays,
    Rays,
    check_faces,
    check_vertices,
    float_array,
    index_array,
    mask_array,
    mesh_arrays,
    nulls_as,
)
from .body import BodyBuffer
from .decoders import (
    FRAME_PARTS,
    FrameChange,
    check_keys,
    check_matrix,
    cut,
    decode_frame,
    decode_mesh,
    decode_pattern,
    decode_points,
    decode_rays,
    decode_trace,
    decode_vertices,
    float32_if_shortest,
    parse_label,
    parse_mask,
    parse_reflectivity,
    quoted,
    read_json,
    read_mapping,
)
from .formats import (
    ANSWER_FORMATS,
    CONTENT_TYPES,
    FRAME_FORMATS,
    JSON,
    MEDIA_TYPES,
    MESH_FILE_FORMATS,
    MESH_FORMATS,
    NPY,
    NPZ,
    PATTERN_FORMATS,
    PCD,
    POINT_FORMATS,
    RAY_FORMATS,
    TRACE_FORMATS,
    VERTEX_FORMATS,
    Buffer,
    declared_format,
    resolve_format,
)
from .npy import array_bytes, npy_header, read_npy
from .npz_reader import MAX_NPZ_MEMBERS, inflated_bytes, read_npz
from .npz_writer import NpzBody, npz_parts

__all__ = [
    "ANSWER_FORMATS",
    "CONTENT_TYPES",
    "FRAME_FORMATS",
    "FRAME_PARTS",
    "JSON",
    "MAX_NPZ_MEMBERS",
    "MEDIA_TYPES",
    "MESH_FILE_FORMATS",
    "MESH_FORMATS",
    "NPY",
    "NPZ",
    "PATTERN_FORMATS",
    "PCD",
    "POINT_FORMATS",
    "RAY_FORMATS",
    "TRACE_FORMATS",
    "VERTEX_FORMATS",
    "BodyBuffer",
    "Buffer",
    "FrameChange",
    "MeshArrays",
    "NpzBody",
    "Rays",
    "array_bytes",
    "check_faces",
    "check_keys",
    "check_accepts",
    "encode_rig_answer",
    "check_matrix",
    "check_vertices",
    "decode_frame",
    "decode_mesh",
    "decode_pattern",
    "decode_points",
    "decode_rays",
    "decode_trace",
    "decode_vertices",
    "encode_answer",
    "encode_json",
    "float32_if_shortest",
    "float_array",
    "index_array",
    "mask_array",
    "json_ready",
    "mesh_arrays",
    "negotiate",
    "npy_header",
    "npy_parts",
    "npz_parts",
    "nulls_as",
    "parse_label",
    "parse_mask",
    "parse_reflectivity",
    "cut",
    "quoted",
    "read_json",
    "read_mapping",
    "read_npy",
    "read_npz",
    "inflated_bytes",
    "declared_format",
    "resolve_format",
]
