"""Job requests (one pydantic body per kind) and the job record the API returns.

Everything a job gets is a JSON document validated here: names of datasets, sequences and
spaces (never paths), numbers with bounds, a build spec mirroring the TOML specs of
``morphspace build`` (docs/file-formats.md, "Motion space specs").
"""

from __future__ import annotations

from enum import Enum
from typing import Annotated, Any, Literal, Union

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, StringConstraints, field_validator, model_validator

from engine.align.captures import FINE_EDGE
from engine.names import NAME
from engine.parameters import MEASURES
from server.commands.build import LAYOUT_FIELDS, LAYOUT_KEYS, foreign_layout_key, layout_sources_problem

NAME_PATTERN = NAME.pattern


def _no_dotdot(name):
    if ".." in name:
        raise ValueError(f"{name!r}: '..' is not allowed in names")
    return name


# every name a job reads or writes (a dataset, space, graph, sequence or node): what the REST
# endpoints can address, so that nothing a job writes is out of their reach
Name = Annotated[str, StringConstraints(pattern=NAME_PATTERN), AfterValidator(_no_dotdot),
                 Field(description="letters, digits, '_', '-', '.'; no leading '.', no '..' (max 128)")]


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ParameterSpec(_Body):
    """The ``[parameters]`` table of a spec: how the sources span high-level parameters."""
    layout: Literal["chain", "grid", "fan"]
    chain: list[Name] | None = Field(None, description="chain and fan: sources in parameter order")
    corners: list[Name] | None = Field(None, min_length=4, max_length=4,
                                       description="grid: sources at u = (0,0), (1,0), (0,1), (1,1)")
    left: Name | None = Field(None, description="fan: the left-turning source")
    right: Name | None = Field(None, description="fan: the right-turning source")
    measures: list[Literal[tuple(MEASURES)]] = Field(min_length=1, max_length=3,  # type: ignore[valid-type]
                                                    description=f"measured parameters: {', '.join(MEASURES)}")
    resolution: int | None = Field(None, ge=2, le=41, description="samples per axis of the parameter map")

    @model_validator(mode="after")
    def _layout_fields(self):
        needed = LAYOUT_KEYS[self.layout]
        missing = [key for key in needed if getattr(self, key) is None]
        if missing:
            raise ValueError(f"a {self.layout} layout needs {', '.join(missing)}")
        foreign = foreign_layout_key(self.layout, {k for k in LAYOUT_FIELDS if getattr(self, k) is not None})
        if foreign is not None:
            raise ValueError(foreign)
        return self

    def placed(self):
        """The source names the layout places, in its keys' order (repeats kept)."""
        names = []
        for key in LAYOUT_KEYS[self.layout]:
            value = getattr(self, key)
            names += value if isinstance(value, list) else [value]
        return names


class BuildSpec(_Body):
    """A motion-space spec as JSON: the TOML spec of ``morphspace build`` without paths."""
    sources: list[Name] = Field(min_length=2, max_length=16, description="sequence names in the dataset")
    parameters: ParameterSpec | None = Field(None, description="omit for a space without parameters")
    epsilon_mm: float | None = Field(None, gt=0, le=100, description="hybrid error bound (default 5 mm)")
    phases: int | None = Field(None, ge=2, le=512, description="phase samples (default: the longest source)")
    rest: str | None = Field(None, max_length=300, pattern=r"^[A-Za-z0-9_][A-Za-z0-9_./-]*$",
                             description="rest mesh inside the dataset, e.g. template/body.obj "
                                         "(default: template/body.obj if present, else the first frame)")

    @field_validator("rest")
    @classmethod
    def _relative(cls, value):
        if value is not None and (".." in value.split("/") or value.startswith("/")):
            raise ValueError("rest must be a path inside the dataset (no '..', not absolute)")
        return value

    @field_validator("sources")
    @classmethod
    def _unique(cls, value):
        if len(set(value)) != len(value):
            raise ValueError("sources must be different sequences")
        return value

    @model_validator(mode="after")
    def _layout_places_the_sources(self):
        """As ``morphspace build`` reads a spec (server.commands.build.read_spec): the layout names
        only sources, each once, and every source."""
        if self.parameters is not None:
            problem = layout_sources_problem(self.parameters.layout, self.parameters.placed(), self.sources)
            if problem is not None:
                raise ValueError(problem)
        return self


class BuildJob(_Body):
    """Build a motion space from sequences of a dataset (``morphspace build``)."""
    kind: Literal["build"]
    dataset: Name = Field(description="an uploaded (or aligned) dataset")
    space: Name = Field(description="name of the motion space to write (spaces/<space>.mspace)")
    spec: BuildSpec
    replace: bool = Field(False, description="replace an existing space of that name")


class AlignJob(_Body):
    """Align unstructured captures into one mesh structure (``morphspace align``); writes a dataset."""
    kind: Literal["align"]
    datasets: list[Name] = Field(min_length=1, max_length=16, description="input datasets")
    output: Name = Field(description="name of the aligned dataset to write")
    only: list[Name] | None = Field(None, max_length=256, description="only these sequences")
    root: str | None = Field(None, max_length=200, description="root frame as SEQUENCE:FRAME or a global index")
    root_choice: Literal["auto", "race", "trial", "apart", "central"] = Field(
        "auto", description="without root: auto, race except on one densely tracked take (a single sequence, 80% of "
                            "the tree's steps or more join neighbours in time), where it is trial (no race); "
                            "race, the trial's two best candidates each align the capture (or 64 "
                            "frames of one over 128) and the more confident alignment's root wins; "
                            "trial, the apart choice and up to 3 other central frames each align 6 "
                             "probe frames and the one that aligns them best is the root (24 frames or more); "
                             "apart, a frame nearly as central as the most central one whose limbs are apart (no "
                             "merged contact tied into every frame); central, the paper's most central frame of "
                             "the tree")
    sequential: bool = Field(False, description="frame-to-frame tracking instead of the tree")
    tree: Literal["mst", "paths", "steps"] = Field(
        "mst", description="mst: the paper's minimum spanning tree; paths: every frame's cheapest path "
                           "from the root with big steps penalised (shallower); steps: every frame's path of "
                           "the least expected error")
    colors: Literal["auto", "on", "off"] = Field(
        "auto", description="vertex colours as local matching cues: auto when the meshes are fine enough "
                            f"for colours to carry texture (median edge under {FINE_EDGE:.1%} of the square root of the "
                            "root's surface area)")
    window: int = Field(2, ge=0, le=10)
    patches: int = Field(30, ge=1, le=500)
    levels: int = Field(4, ge=1, le=8)
    retries: int = Field(3, ge=0, le=10)
    repair_budget: float = Field(0.25, ge=0, le=10, description="pairwise alignments per frame that repairing "
                                                               "low-confidence frames may spend (0: no repair)")
    swing_limbs: bool = Field(False, description="swing limbs onto the parts of a frame nothing covers in the "
                                                 "coarse matching (an arm thrown into a punch)")
    reach_limbs: bool = Field(True, description="pull the root's extremities (hands, feet, head, a sleeve's or "
                                                "hem's end) onto the parts of a frame nothing covers, bending "
                                                "the limb as-rigid-as-possible")
    graft_limbs: bool = Field(False, description="in the repair, give a frame the root left flagged the limbs "
                                                 "of the other frames' poses that fit it clearly better and "
                                                 "align it again from there")
    seed: int = Field(0, ge=0, le=2**31 - 1)
    units: Literal["auto", "m", "cm", "mm"] = Field(
        "auto", description="length unit of the input meshes; auto: from the model's size (a person is "
                            "0.5-2.5 m across), else the dataset's metadata")
    up: Literal["auto", "y", "z"] = Field(
        "auto", description="up axis of the input meshes; auto: the axis along which the subject keeps to a "
                            "floor, else the longer of the body's Y and Z extents, else the dataset's metadata")
    replace: bool = False

    @model_validator(mode="after")
    def _root_given_once(self):
        if self.root is not None and self.root_choice != "auto":
            raise ValueError(f"root_choice {self.root_choice}: the root is given (root {self.root}), so no root is "
                             "chosen; give one or the other")
        return self


class IngestJob(_Body):
    """Validate every frame of a dataset and normalise it (frame names, OBJ, meta.json, manifest)."""
    kind: Literal["ingest"]
    dataset: Name
    output: Name | None = Field(None, description="write a new dataset (default: replace the input)")
    replace: bool = Field(False, description="with output: replace an existing dataset of that name")


class TrackEntry(_Body):
    """A request of an export's parameter track."""
    time: float = Field(ge=0, le=3600, description="seconds from the start of the clip")
    params: dict[str, float] = Field(description="{name: value} requested from then on")


class ExportSpec(_Body):
    """A clip to export (docs/exports.md): played by the real-time player, written as ``format``."""
    format: Literal["glb", "usd", "obj", "ply", "vat"] = Field(
        "glb", description="glb, usd, obj/ply (a zip of one file per frame) or vat (a zip: mesh.glb, positions.png, "
                           "vat.json)")
    params: dict[str, float] = Field(default_factory=dict, description="{name: value} at t = 0 (missing ones: the "
                                                                       "middle of their range)")
    track: list[TrackEntry] = Field(default_factory=list, max_length=1000, description="later requests")
    duration: float = Field(10.0, gt=0, le=3600, description="seconds")
    rate: float = Field(60.0, gt=0, le=240, description="frames per second")
    mode: Literal["linear", "hybrid", "nonlinear"] = "hybrid"
    smoothing: float = Field(0.25, ge=0, le=60, description="the player's parameter time constant (s)")
    precision: Literal["int16", "float32"] = Field("int16", description="glTF: int16 (KHR_mesh_quantization) or "
                                                                        "float32")
    interpolation: Literal["LINEAR", "STEP"] = Field("LINEAR", description="glTF weights sampling")


class GraphExportSpec(_Body):
    """A recorded motion-graph performance to export (docs/exports.md, "A motion-graph performance")."""
    format: Literal["glb", "usd", "obj", "ply", "vat"] = Field("glb", description="as for a clip")
    recording: dict[str, Any] = Field(description="a graph recording (docs/file-formats.md, \"Graph recordings\"): "
                                                  "morphspace play --record or the browser's Record button")
    precision: Literal["int16", "float32"] = Field("int16", description="glTF: int16 or float32")
    interpolation: Literal["LINEAR", "STEP"] = Field("LINEAR", description="glTF weights sampling")


CLIP_ONLY = ("params", "track", "duration", "rate", "mode", "smoothing")  # a space's clip; a recording has its own


class ExportJob(ExportSpec):
    """Export a clip of a motion space, or a recorded performance of a motion graph (a long one;
    short ones: POST /v1/spaces/{name}/export, POST /v1/graphs/{name}/export)."""
    kind: Literal["export"]
    space: Name | None = Field(None, description="a motion space (a clip: params, track, duration, ...)")
    graph: Name | None = Field(None, description="or a motion graph (with recording)")
    recording: dict[str, Any] | None = Field(None, description="with graph: the graph recording to export")

    @model_validator(mode="after")
    def _space_or_graph(self):
        if (self.space is None) == (self.graph is None):
            raise ValueError("give either space (a clip) or graph (with recording)")
        if (self.graph is None) != (self.recording is None):
            raise ValueError("recording goes with graph (a motion graph's recorded performance), and graph needs one")
        clip_only = sorted(self.model_fields_set & set(CLIP_ONLY))
        if self.graph is not None and clip_only:
            raise ValueError(f"a graph export replays its recording (its own clock, blend mode and requests): "
                             f"leave out {', '.join(clip_only)}")
        return self


class GraphNode(_Body):
    """A node of a motion graph: a motion space of the server under a name."""
    name: Name
    space: Name = Field(description="a motion space (spaces/<space>.mspace)")
    return_to: Name | None = Field(None, description="one-shot nodes: the cyclic node to go back to")


class GraphWindow(_Body):
    """How windows of motion are sampled and compared (docs/file-formats.md, "Motion graph specs")."""
    window_frames: int = Field(6, ge=2, le=60)
    window_step: float = Field(1.0 / 30.0, gt=0, le=0.5)
    vertices: int = Field(300, ge=10, le=100_000)
    velocity_weight: float = Field(0.1, ge=0, le=10)
    phases: int = Field(24, ge=4, le=256)
    per_axis: int = Field(5, ge=1, le=21)


class GraphJob(_Body):
    """Build a motion graph over spaces of the server (``morphspace build-graph``)."""
    kind: Literal["graph"]
    graph: Name = Field(description="name of the graph to write (spaces/<graph>.mgraph)")
    nodes: list[GraphNode] = Field(min_length=2, max_length=32)
    edges: list[Annotated[list[Name], Field(min_length=2, max_length=2)]] = Field(
        min_length=1, max_length=1024, description="allowed transitions as [from, to] node names")
    window: GraphWindow = Field(default_factory=GraphWindow)
    replace: bool = Field(False, description="replace an existing graph of that name")

    @model_validator(mode="after")
    def _known_nodes(self):
        names = [n.name for n in self.nodes]
        if len(set(names)) != len(names):
            raise ValueError("node names must differ")
        for edge in self.edges:
            if any(e not in names for e in edge):
                raise ValueError(f"edge {edge}: both ends must be nodes ({', '.join(names)})")
        from engine.graph import GraphError
        from engine.graph.build import check_connected

        try:   # as build-graph checks it, before anything is queued
            check_connected(names, [(names.index(a), names.index(b)) for a, b in self.edges])
        except GraphError as exc:
            raise ValueError(str(exc)) from None
        return self


JobRequest = Annotated[Union[BuildJob, AlignJob, IngestJob, ExportJob, GraphJob], Field(discriminator="kind")]


class JobStatus(str, Enum):
    queued = "queued"
    running = "running"
    succeeded = "succeeded"
    failed = "failed"
    cancelled = "cancelled"


class JobRecord(BaseModel):
    id: str
    kind: Literal["build", "align", "ingest", "export", "graph"]
    status: JobStatus
    stage: str = Field(description="what it is doing: queued, starting, read, tetrahedralise, ... publish")
    progress: float = Field(ge=0, le=1, description="0..1, never decreasing within a run of the job (a run "
                                                    "stopped by a clean shutdown starts again from 0 under the "
                                                    "same attempt number)")
    params: dict[str, Any] = Field(description="the request")
    result: dict[str, Any] | None = Field(description="what a succeeded job produced (with its url)")
    error: str | None = Field(description="why it failed or was cancelled")
    log: list[str] = Field(description="the last lines of the job's log")
    attempts: int = Field(description="times it has been started (an interrupted job is started again once)")
    max_attempts: int
    cancel_requested: bool
    executor: str | None = Field(description="local or dask")
    worker: dict[str, Any] | None = Field(description="where it runs: local {pid}, or dask {key}")
    created_at: float = Field(description="Unix seconds")
    started_at: float | None
    finished_at: float | None
    updated_at: float


class JobList(BaseModel):
    jobs: list[JobRecord]
