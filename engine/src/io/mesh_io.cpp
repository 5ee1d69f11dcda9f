#include "proxima/io/mesh_io.hpp"

#include <algorithm>
#include <array>
#include <cctype>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <numeric>
#include <set>
#include <string_view>
#include <system_error>
#include <tuple>

#include <assimp/BaseImporter.h>
#include <assimp/DefaultIOSystem.h>
#include <assimp/MemoryIOWrapper.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <assimp/Importer.hpp>

#include "io/gltf.hpp"
#include "io/gzip.hpp"
#include "io/obj.hpp"
#include "io/ply_off.hpp"

namespace proxima {

namespace {

// Appends every mesh the node and its children instance. assimp's own validation step
// (aiProcess_ValidateDataStructure) cannot be used: it rejects real files whose scene assimp built
// itself (desk.obj of the shared data: "mFaces[444] is a LINE but mPrimitiveTypes does not report
// the LINE flag"). So the indices this code follows are checked here instead: a mesh index or a
// vertex index outside its array is an error, not a read out of bounds.
Status collect(const aiScene* scene, const aiNode* node, const aiMatrix4x4& parent,
               TriangleMesh& out) {
    const aiMatrix4x4 transform = parent * node->mTransformation;
    const bool identity = transform.IsIdentity();
    for (unsigned m = 0; m < node->mNumMeshes; ++m) {
        const unsigned index = node->mMeshes[m];
        const aiMesh* mesh = index < scene->mNumMeshes ? scene->mMeshes[index] : nullptr;
        if (mesh == nullptr || (mesh->mNumVertices > 0 && mesh->mVertices == nullptr) ||
            (mesh->mNumFaces > 0 && mesh->mFaces == nullptr)) {
            return invalid_argument("node '" + std::string(node->mName.C_Str()) + "' names mesh " +
                                    std::to_string(index) + " of " +
                                    std::to_string(scene->mNumMeshes) + ", which has no data");
        }
        const auto base = static_cast<std::uint32_t>(out.vertices.size());
        for (unsigned v = 0; v < mesh->mNumVertices; ++v) {
            aiVector3D p = mesh->mVertices[v];
            if (!identity) {
                p = transform * p;
            }
            out.vertices.push_back({p.x, p.y, p.z});
        }
        for (unsigned f = 0; f < mesh->mNumFaces; ++f) {
            const aiFace& face = mesh->mFaces[f];
            if (face.mNumIndices != 3) {
                continue;  // points and lines (polygons were triangulated on import)
            }
            for (unsigned k = 0; k < 3; ++k) {
                if (face.mIndices[k] >= mesh->mNumVertices) {
                    return invalid_argument("mesh " + std::to_string(index) + ", face " +
                                            std::to_string(f) + ": vertex index " +
                                            std::to_string(face.mIndices[k]) + " of " +
                                            std::to_string(mesh->mNumVertices));
                }
            }
            out.triangles.push_back(
                {base + face.mIndices[0], base + face.mIndices[1], base + face.mIndices[2]});
        }
    }
    for (unsigned c = 0; c < node->mNumChildren; ++c) {
        if (node->mChildren[c] == nullptr) {
            continue;
        }
        if (Status s = collect(scene, node->mChildren[c], transform, out); !s.ok()) {
            return s;
        }
    }
    return {};
}

// Merges vertices with identical coordinates, keeping the first occurrence's index order;
// `file_vertex[k]` becomes the input index of kept vertex k's first occurrence.
void weld(TriangleMesh& mesh, std::vector<std::uint32_t>& file_vertex) {
    std::map<std::tuple<double, double, double>, std::uint32_t> seen;
    std::vector<std::uint32_t> remap(mesh.vertices.size());
    std::vector<Vec3> kept;
    std::vector<std::uint32_t> first;
    kept.reserve(mesh.vertices.size());
    for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
        const auto& p = mesh.vertices[v];
        // +0.0 and -0.0 are the same point.
        const auto key = std::make_tuple(p.x + 0.0, p.y + 0.0, p.z + 0.0);
        auto [it, inserted] = seen.emplace(key, static_cast<std::uint32_t>(kept.size()));
        if (inserted) {
            kept.push_back(p);
            first.push_back(static_cast<std::uint32_t>(v));
        }
        remap[v] = it->second;
    }
    for (auto& t : mesh.triangles) {
        for (auto& i : t) {
            i = remap[i];
        }
    }
    mesh.vertices = std::move(kept);
    file_vertex = std::move(first);
}

// A triangle soup: no vertex is used by two triangle corners (STL, and exporters that write
// every corner on its own).
bool is_triangle_soup(const TriangleMesh& mesh) {
    std::vector<bool> used(mesh.vertices.size(), false);
    for (const auto& t : mesh.triangles) {
        for (const auto v : t) {
            if (used[v]) {
                return false;
            }
            used[v] = true;
        }
    }
    return true;
}

// The whole file, or an error naming it.
Status read_file(const std::string& path, std::string& out) {
    std::ifstream in(path, std::ios::binary);
    if (!in) {
        return invalid_argument("mesh file '" + path + "': cannot be opened for reading");
    }
    std::error_code ec;
    const std::uintmax_t size = std::filesystem::file_size(path, ec);
    if (ec) {
        return invalid_argument("mesh file '" + path + "': cannot get its size: " + ec.message());
    }
    out.resize(static_cast<std::size_t>(size));
    in.read(out.data(), static_cast<std::streamsize>(size));
    if (in.bad()) {
        return invalid_argument("mesh file '" + path + "': read error");
    }
    out.resize(static_cast<std::size_t>(in.gcount()));  // the file may have shrunk meanwhile
    return {};
}

// The first bytes of the file, enough to recognise PLY and OFF (with a few comment lines).
std::string read_head(const std::string& path) {
    constexpr std::size_t HEAD_BYTES = std::size_t{64} * 1024;
    std::string head(HEAD_BYTES, '\0');
    std::ifstream in(path, std::ios::binary);
    in.read(head.data(), static_cast<std::streamsize>(head.size()));
    head.resize(static_cast<std::size_t>(std::max<std::streamsize>(in.gcount(), 0)));
    return head;
}

// The formats read through assimp: STL only. Every other assimp importer is removed before
// reading, so a file can never reach one of the ~40 importers nobody fuzzes (not even through
// assimp's fall-back detection by content). OBJ and glTF went through assimp until fuzzing found
// crashes in Debian's assimp 5.2.5 for both (docs/reliability.md, "Fuzzing"); they have readers
// of their own now (obj.cpp, gltf.cpp), like PLY and OFF.
constexpr std::array<std::string_view, 1> ASSIMP_FORMATS = {"stl"};

// The formats with a reader of our own, by extension.
enum class OwnReader { none, obj, gltf, glb };
OwnReader own_reader(std::string_view format) {
    return format == "obj"    ? OwnReader::obj
           : format == "gltf" ? OwnReader::gltf
           : format == "glb"  ? OwnReader::glb
                              : OwnReader::none;
}

std::string lower(std::string_view text) {
    std::string out(text);
    std::transform(out.begin(), out.end(), out.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return out;
}

bool is_assimp_format(std::string_view format) {
    return std::find(ASSIMP_FORMATS.begin(), ASSIMP_FORMATS.end(), format) != ASSIMP_FORMATS.end();
}

// An extension some reader claims by name (no content detection needed).
bool is_known_extension(const std::string& key) {
    return key == "ply" || key == "off" || own_reader(key) != OwnReader::none ||
           is_assimp_format(key);
}

// Serves the buffer under its own name only. assimp's MemoryIOSystem serves it under every name
// that starts with its magic prefix (an OBJ read from memory was read as its own fall-back
// material library, "<magic>.mtl", when OBJ still went through assimp).
class BufferOnlySystem : public Assimp::MemoryIOSystem {
  public:
    BufferOnlySystem(std::string_view data, std::string name)
        : MemoryIOSystem(reinterpret_cast<const std::uint8_t*>(data.data()), data.size(), nullptr),
          m_name(std::move(name)) {}
    bool Exists(const char* file) const override {
        return file != nullptr && m_name == file && MemoryIOSystem::Exists(file);
    }
    Assimp::IOStream* Open(const char* file, const char* mode) override {
        return file != nullptr && m_name == file ? MemoryIOSystem::Open(file, mode) : nullptr;
    }

  private:
    const std::string m_name;
};

// Unregisters (and frees: UnregisterLoader does not) every importer that claims none of
// ASSIMP_FORMATS' extensions.
void keep_allowed_importers(Assimp::Importer& importer) {
    std::vector<Assimp::BaseImporter*> refused;
    for (std::size_t i = 0; i < importer.GetImporterCount(); ++i) {
        Assimp::BaseImporter* candidate = importer.GetImporter(i);
        std::set<std::string> extensions;
        candidate->GetExtensionList(extensions);
        const bool allowed = std::any_of(extensions.begin(), extensions.end(),
                                         [](const std::string& e) { return is_assimp_format(e); });
        if (!allowed) {
            refused.push_back(candidate);
        }
    }
    for (Assimp::BaseImporter* candidate : refused) {
        importer.UnregisterLoader(candidate);
        delete candidate;
    }
}

// Triangulation keeps polygon order; degenerate triangles are kept (they are legal input for
// every query). No joining (it would also merge on normals and UVs), no reordering; no validation
// step (collect() checks what it follows).
constexpr unsigned ASSIMP_FLAGS = aiProcess_Triangulate;

StatusOr<TriangleMesh> collect_scene(const Assimp::Importer& importer, const aiScene* scene,
                                     const std::string& name) {
    if (scene == nullptr || scene->mRootNode == nullptr) {
        return invalid_argument("mesh file '" + name +
                                "': cannot be read: " + importer.GetErrorString());
    }
    TriangleMesh mesh;
    if (Status s = collect(scene, scene->mRootNode, aiMatrix4x4(), mesh); !s.ok()) {
        return invalid_argument("mesh file '" + name + "': " + s.message());
    }
    return mesh;
}

StatusOr<TriangleMesh> read_with_assimp(const std::string& path) {
    Assimp::Importer importer;
    keep_allowed_importers(importer);
    const aiScene* scene = importer.ReadFile(path, ASSIMP_FLAGS);
    return collect_scene(importer, scene, path);
}

StatusOr<TriangleMesh> read_memory_with_assimp(std::string_view data, const std::string& format,
                                               const std::string& name) {
    Assimp::Importer importer;
    keep_allowed_importers(importer);
    // An I/O system that serves only the buffer: nothing else is read.
    const std::string magic = std::string(AI_MEMORYIO_MAGIC_FILENAME) + "." + format;
    importer.SetIOHandler(new BufferOnlySystem(data, magic));
    const aiScene* scene = importer.ReadFile(magic, ASSIMP_FLAGS);
    return collect_scene(importer, scene, name);
}

Status unsupported_format(const std::string& name, const std::string& format) {
    return invalid_argument("mesh file '" + name + "': unsupported format '" + format +
                            "' (accepted: " + std::string(ACCEPTED_MESH_FORMATS) + ")");
}

// What read_mesh and read_mesh_from_memory do after reading: validate, then weld (options.weld),
// keeping the map back to the file's vertex ids where asked.
StatusOr<TriangleMesh> finish(StatusOr<TriangleMesh> read, const std::string& name,
                              const MeshReadOptions& options,
                              std::vector<std::uint32_t>* file_vertex) {
    if (!read.ok()) {
        return read.status();
    }
    TriangleMesh mesh = std::move(read).value();
    // Validate before welding: the weld's ordered map cannot hold NaN keys.
    if (Status s = validate_mesh(mesh, "mesh file '" + name + "'"); !s.ok()) {
        return s;
    }
    const bool weld_it = options.weld == WeldMode::always ||
                         (options.weld == WeldMode::triangle_soups && is_triangle_soup(mesh));
    std::vector<std::uint32_t> ids;
    if (weld_it) {
        weld(mesh, ids);
    } else if (file_vertex != nullptr) {
        ids.resize(mesh.vertices.size());
        std::iota(ids.begin(), ids.end(), 0u);
    }
    if (file_vertex != nullptr) {
        *file_vertex = std::move(ids);
    }
    return mesh;
}

}  // namespace

StatusOr<TriangleMesh> read_mesh(const std::string& path, const MeshReadOptions& options,
                                 std::vector<std::uint32_t>* file_vertex) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) {
        return not_found("mesh file '" + path + "': no such file");
    }
    if (std::filesystem::is_directory(path, ec)) {
        return invalid_argument("mesh file '" + path + "': is a directory");
    }
    // A FIFO or a device would block or never end.
    if (!std::filesystem::is_regular_file(path, ec)) {
        return invalid_argument("mesh file '" + path + "': not a regular file");
    }
    {
        std::ifstream probe(path, std::ios::binary);
        if (!probe) {
            return invalid_argument("mesh file '" + path + "': cannot be opened for reading");
        }
    }
    const std::string extension = lower(std::filesystem::path(path).extension().string());
    const std::string key = extension.empty() ? std::string() : extension.substr(1);
    // A name no reader claims: its first bytes decide (gzip, PLY or OFF), read once.
    const std::string head =
        key == "gz" || is_known_extension(key) ? std::string() : read_head(path);
    // gzip: by extension, or by its magic bytes under a name no reader claims. Decompressed in
    // memory, then read as the file it holds (named by the extension before ".gz").
    if (key == "gz" || detail::is_gzip(head)) {
        std::string packed;
        if (Status s = read_file(path, packed); !s.ok()) {
            return s;
        }
        const std::string inner =
            key == "gz" ? lower(std::filesystem::path(path).stem().extension().string()) : "";
        return read_mesh_from_memory(packed, inner.empty() ? "gz" : inner.substr(1) + ".gz", path,
                                     options, file_vertex);
    }
    // PLY, OFF, OBJ and glTF are read by our own readers, in double: Debian's assimp reads at
    // float precision. PLY and OFF are also recognised by content under any other extension
    // (frames without one).
    detail::NativeMeshFormat format = detail::native_format_from_extension(path);
    const OwnReader own = own_reader(key);
    const bool assimp = !key.empty() && is_assimp_format(key);
    if (format == detail::NativeMeshFormat::none && own == OwnReader::none && !assimp) {
        format = detail::native_format_from_content(head);
        if (format == detail::NativeMeshFormat::none) {
            return unsupported_format(path, extension.empty() ? "(no extension)" : extension);
        }
    }
    if (assimp) {
        return finish(read_with_assimp(path), path, options, file_vertex);
    }
    std::string data;
    if (Status s = read_file(path, data); !s.ok()) {
        return s;
    }
    if (own == OwnReader::obj) {
        return finish(detail::read_obj(path, data), path, options, file_vertex);
    }
    if (own == OwnReader::gltf || own == OwnReader::glb) {
        // External buffers: files in the .gltf's own directory or below it, named relatively.
        const std::filesystem::path dir = std::filesystem::path(path).parent_path();
        const detail::GltfBufferLoader load = [&](const std::string& uri) -> StatusOr<std::string> {
            const std::filesystem::path relative(uri);
            const bool leaves =
                std::any_of(relative.begin(), relative.end(),
                            [](const std::filesystem::path& part) { return part == ".."; });
            if (uri.empty() || relative.is_absolute() || relative.has_root_name() || leaves) {
                return invalid_argument(
                    "mesh file '" + path + "': buffer '" + uri +
                    "': only files beside the glTF file (or below it) are read");
            }
            const std::string file = (dir / relative).string();
            std::error_code error;
            if (!std::filesystem::is_regular_file(file, error)) {
                return not_found("mesh file '" + path + "': buffer '" + uri + "': no such file");
            }
            std::string bytes;
            if (Status s = read_file(file, bytes); !s.ok()) {
                return s;
            }
            return bytes;
        };
        return finish(detail::read_gltf(path, data, own == OwnReader::glb, load), path, options,
                      file_vertex);
    }
    return finish(format == detail::NativeMeshFormat::ply ? detail::read_ply(path, data)
                                                          : detail::read_off(path, data),
                  path, options, file_vertex);
}

StatusOr<TriangleMesh> read_mesh_from_memory(std::string_view data, std::string_view format,
                                             const std::string& name,
                                             const MeshReadOptions& options,
                                             std::vector<std::uint32_t>* file_vertex) {
    std::string key = lower(format);
    if (key.starts_with('.')) {
        key.erase(0, 1);
    }
    const bool gz_format = key == "gz" || key.ends_with(".gz");
    if (gz_format || detail::is_gzip(data)) {
        if (gz_format) {
            key.erase(key.size() - std::min<std::size_t>(key.size(), 3));  // "ply.gz" -> "ply"
            if (key.ends_with('.')) {
                key.pop_back();
            }
        }
        auto unpacked = detail::gunzip(data, name, options.max_uncompressed_bytes);
        if (!unpacked.ok()) {
            return unpacked.status();
        }
        if (detail::is_gzip(unpacked.value())) {
            return invalid_argument("mesh file '" + name +
                                    "': gzip data holds gzip data again (compressed twice)");
        }
        if (key.empty()) {
            // "gz" alone: PLY or OFF, recognised by content.
            const auto content = detail::native_format_from_content(unpacked.value());
            if (content == detail::NativeMeshFormat::none) {
                return unsupported_format(name, "(gzip data that is neither PLY nor OFF)");
            }
            key = content == detail::NativeMeshFormat::ply ? "ply" : "off";
        }
        return read_mesh_from_memory(unpacked.value(), key, name, options, file_vertex);
    }
    if (key == "ply") {
        return finish(detail::read_ply(name, data), name, options, file_vertex);
    }
    if (key == "off") {
        return finish(detail::read_off(name, data), name, options, file_vertex);
    }
    switch (own_reader(key)) {
        case OwnReader::obj:
            return finish(detail::read_obj(name, data), name, options, file_vertex);
        case OwnReader::gltf:
        case OwnReader::glb: {
            // Nothing but the bytes given is read: a .gltf's external buffers are not found.
            const detail::GltfBufferLoader none =
                [&](const std::string& uri) -> StatusOr<std::string> {
                return not_found("mesh file '" + name + "': buffer '" + uri +
                                 "': only buffers inside the data are read from memory");
            };
            return finish(detail::read_gltf(name, data, key == "glb", none), name, options,
                          file_vertex);
        }
        case OwnReader::none:
            break;
    }
    if (!is_assimp_format(key)) {
        return unsupported_format(name, std::string(format));
    }
    return finish(read_memory_with_assimp(data, key, name), name, options, file_vertex);
}

Status write_off(const std::string& path, const TriangleMesh& mesh) {
    std::FILE* f = std::fopen(path.c_str(), "w");
    if (f == nullptr) {
        return invalid_argument("cannot write '" + path + "'");
    }
    std::fprintf(f, "OFF\n%zu %zu 0\n", mesh.vertices.size(), mesh.triangles.size());
    for (const auto& v : mesh.vertices) {
        std::fprintf(f, "%.17g %.17g %.17g\n", v.x, v.y, v.z);
    }
    for (const auto& t : mesh.triangles) {
        std::fprintf(f, "3 %u %u %u\n", t[0], t[1], t[2]);
    }
    const bool ok = std::fclose(f) == 0;
    return ok ? Status{} : invalid_argument("cannot write '" + path + "'");
}

}  // namespace proxima
