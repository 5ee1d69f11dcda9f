#pragma once
// Recorded sequences of frames for `proxima play` and the load harness: a folder of numbered mesh
// files (frame_000.obj, frame_001.obj, ... or the frames/<scene> pairs of ../shared/data), one
// file per frame, each frame's objects the file (or, with split_components, each connected
// component of it, in the order of their first triangle). Frame k's objects become an update of
// frame k-1's scene: a positions-only update where every object keeps its topology, otherwise a
// topology change (diff_frames below), so a sequence can break objects into pieces mid-stream.

#include <cstddef>
#include <limits>
#include <string>
#include <vector>

#include "common/local_scene.hpp"
#include "proxima/scene.hpp"
#include "proxima/status.hpp"

namespace proxima::client {

// One recorded frame: the scene's objects at that instant, in order.
struct SequenceFrame {
    std::string file;        // the file it was read from ("" for a sequence built in memory)
    std::size_t number = 0;  // its position in the folder's natural order (before --frames)
    std::vector<InputObject> objects;
};

struct Sequence {
    std::string dir;
    // The recorded rate (frames per second) from DIR/sequence.json {"fps": N}; 0 when the folder
    // does not say. Its "frames": [{"file": NAME, "objects": [names]}] (as `proxima generate
    // sequence` writes it) names the objects of a frame file when the counts agree.
    double fps = 0;
    std::vector<SequenceFrame> frames;
};

// Quake II steps its MD2 animations at its 10 Hz server rate: an MD2's recorded rate.
inline constexpr double MD2_KEYFRAME_FPS = 10.0;

struct SequenceOptions {
    bool split_components = false;
    // Merge vertices with bit-identical positions within every file (--weld, WeldMode::always).
    // Off by default, as for `proxima distance`: only triangle soups are welded, and a vertex of
    // an indexed file is its index in the file, so two vertices that meet in one frame do not
    // turn that frame into a topology change.
    bool weld = false;
    // Frames [begin, end) of the folder's natural order (--frames A:B).
    std::size_t begin = 0;
    std::size_t end = std::numeric_limits<std::size_t>::max();
};

// Natural order of file names: runs of digits compare as numbers ("frame_9" < "frame_10"; with
// equal values the shorter run first), the rest byte by byte.
bool natural_less(const std::string& a, const std::string& b);

// The mesh files of `dir` (the extensions read_mesh takes, each also .gz), in natural order.
// not_found for a missing folder, invalid_argument for a folder without mesh files.
StatusOr<std::vector<std::string>> list_frame_files(const std::string& dir);

// Reads the folder (every file of the range, up front, so that file reading is not part of a
// frame's latency). Errors name the file; a frame without objects is invalid_argument.
// `dir` may also be a Quake II MD2 model (a file ending in .md2, proxima/io/md2.hpp): its
// keyframes are the frames (one topology, so every frame after the first moves vertices only),
// recorded at MD2_KEYFRAME_FPS, and every frame's `file` is the model.
StatusOr<Sequence> load_sequence(const std::string& dir, const SequenceOptions& options = {});

// Same vertex count and the same triangles.
bool same_topology(const TriangleMesh& a, const TriangleMesh& b);

// The update that turns a scene holding `prev` (ids `ids`, in order) into `next`, keeping the
// scene's object order equal to `next`'s order:
//  - the same number of objects: each object with the same topology gets its positions (nothing
//    when they did not move), each other one is replaced by its new mesh (a one-fragment topology
//    change);
//  - a different number: the longest runs of same-topology objects at the front and back keep
//    their ids and get positions; the first object between them is replaced by all new objects
//    between them (an object breaking into pieces: its fragments take its place), the other old
//    ones between them are removed; objects appended after all old ones are additions. When the
//    names say which new objects are pieces of which old one ("ball3" -> "ball3.piece0",
//    "ball3.piece1", ...; separators '.', '/', '#'), each old object between the runs is
//    replaced by its own pieces instead (removed when it has none).
struct FrameDiff {
    SceneUpdate update;
    bool topology_change = false;
};
FrameDiff diff_frames(const std::vector<InputObject>& prev, const std::vector<ObjectId>& ids,
                      const std::vector<InputObject>& next);

}  // namespace proxima::client
