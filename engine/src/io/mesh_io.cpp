#include "proxima/io/mesh_io.hpp"

#include <algorithm>
#include <array>
#include <cctype>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
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

#include <nlohmann/json.hpp>

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

// Merges vertices with identical coordinates, keeping the first occurrence's index order.
void weld(TriangleMesh& mesh) {
    std::map<std::tuple<double, double, double>, std::uint32_t> seen;
    std::vector<std::uint32_t> remap(mesh.vertices.size());
    std::vector<Vec3> kept;
    kept.reserve(mesh.vertices.size());
    for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
        const auto& p = mesh.vertices[v];
        // +0.0 and -0.0 are the same point.
        const auto key = std::make_tuple(p.x + 0.0, p.y + 0.0, p.z + 0.0);
        auto [it, inserted] = seen.emplace(key, static_cast<std::uint32_t>(kept.size()));
        if (inserted) {
            kept.push_back(p);
        }
        remap[v] = it->second;
    }
    for (auto& t : mesh.triangles) {
        for (auto& i : t) {
            i = remap[i];
        }
    }
    mesh.vertices = std::move(kept);
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

// The formats read through assimp; every other assimp importer is removed before reading, so a
// file can never reach one of the ~40 importers nobody fuzzes (not even through assimp's
// fall-back detection by content). Debian's assimp is not instrumented: the allowlist keeps the
// attack surface to the formats the project tests and fuzzes.
constexpr std::array<std::string_view, 4> ASSIMP_FORMATS = {"obj", "stl", "gltf", "glb"};

std::string lower(std::string_view text) {
    std::string out(text);
    std::transform(out.begin(), out.end(), out.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return out;
}

bool is_assimp_format(std::string_view format) {
    return std::find(ASSIMP_FORMATS.begin(), ASSIMP_FORMATS.end(), format) != ASSIMP_FORMATS.end();
}

// Material libraries are never read. Debian's assimp 5.2.5 crashes (a write through a null
// material) on an .mtl whose first statement is a texture map, such as "map_Kd a" before any
// "newmtl": `proxima distance x.obj` died with SIGSEGV when x.obj named such a file, or when its
// mtllib was missing and x.mtl beside it held one (assimp's fall-back name). Found by fuzz_mesh.
// Geometry never needs materials, so no importer may open an .mtl.
bool is_material_library(const char* file) {
    const std::string name = lower(file == nullptr ? "" : file);
    return name.size() >= 4 && name.compare(name.size() - 4, 4, ".mtl") == 0;
}

class GeometryFileSystem : public Assimp::DefaultIOSystem {
  public:
    bool Exists(const char* file) const override {
        return !is_material_library(file) && DefaultIOSystem::Exists(file);
    }
    Assimp::IOStream* Open(const char* file, const char* mode) override {
        return is_material_library(file) ? nullptr : DefaultIOSystem::Open(file, mode);
    }
};

// Serves the buffer under its own name only. assimp's MemoryIOSystem serves it under every name
// that starts with its magic prefix, so an OBJ read from memory was also read as its own fall-back
// material library ("<magic>.mtl"), and reached the crash above.
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
// ASSIMP_FORMATS' extensions. The glTF 1.0 and 2.0 importers both claim .gltf/.glb and stay.
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
    // From the file system, so that a .gltf's external buffers load; never an .mtl.
    importer.SetIOHandler(new GeometryFileSystem());
    const aiScene* scene = importer.ReadFile(path, ASSIMP_FLAGS);
    return collect_scene(importer, scene, path);
}

StatusOr<TriangleMesh> read_memory_with_assimp(std::string_view data, const std::string& format,
                                               const std::string& name) {
    Assimp::Importer importer;
    keep_allowed_importers(importer);
    // An I/O system that serves only the buffer: references to other files (a .gltf's buffers, an
    // .obj's .mtl) fail instead of reaching the file system.
    const std::string magic = std::string(AI_MEMORYIO_MAGIC_FILENAME) + "." + format;
    importer.SetIOHandler(new BufferOnlySystem(data, magic));
    const aiScene* scene = importer.ReadFile(magic, ASSIMP_FLAGS);
    return collect_scene(importer, scene, name);
}

std::uint32_t little_u32(std::string_view data, std::size_t at) {
    std::uint32_t v = 0;
    for (int b = 3; b >= 0; --b) {
        v = (v << 8) | static_cast<unsigned char>(data[at + static_cast<std::size_t>(b)]);
    }
    return v;
}

// Debian's assimp 5.2.5 sizes its buffers from a binary glTF's header before comparing them with
// the file: a 49-byte .glb whose JSON chunk claimed 687 MB took 5 s and 800 MB (fuzz_mesh,
// tests/fuzz/regressions/mesh/). Every length in the header and chunk headers must fit in the
// bytes that are there. Other problems (magic, versions, chunk types) are left to assimp.
Status check_glb(std::string_view data, const std::string& name) {
    const auto error = [&](const std::string& what) {
        return invalid_argument("mesh file '" + name + "': binary glTF: " + what);
    };
    if (data.size() < 12) {
        return error("the file is " + std::to_string(data.size()) +
                     " bytes, shorter than the 12-byte header");
    }
    if (data.substr(0, 4) != "glTF") {
        return {};
    }
    const std::uint32_t version = little_u32(data, 4);
    const std::uint64_t length = little_u32(data, 8);
    if (length > data.size()) {
        return error("the header declares " + std::to_string(length) + " bytes, the file holds " +
                     std::to_string(data.size()));
    }
    if (version == 1) {
        // glTF 1.0 (KHR_binary_glTF): a 20-byte header, then the scene's JSON.
        if (data.size() < 20) {
            return error("the file is " + std::to_string(data.size()) +
                         " bytes, shorter than the 20-byte glTF 1.0 header");
        }
        const std::uint64_t content = little_u32(data, 12);
        if (content > data.size() - 20) {
            return error("the scene declares " + std::to_string(content) + " bytes, " +
                         std::to_string(data.size() - 20) + " follow the header");
        }
        return {};
    }
    // glTF 2.0: chunks of (length, type, data) after the 12-byte header.
    std::size_t at = 12;
    while (data.size() - at >= 8) {
        const std::uint64_t chunk = little_u32(data, at);
        if (chunk > data.size() - at - 8) {
            return error("the chunk at byte " + std::to_string(at) + " declares " +
                         std::to_string(chunk) + " bytes, " + std::to_string(data.size() - at - 8) +
                         " follow it");
        }
        at += 8 + static_cast<std::size_t>(chunk);
    }
    return {};
}

// The glTF document of a .gltf (the whole file) or a .glb (its first chunk, when the header
// checked by check_glb says it is JSON); empty for other formats.
std::string_view gltf_json(std::string_view data, std::string_view format) {
    if (format == "gltf") {
        return data;
    }
    if (format != "glb" || data.size() < 20 || data.substr(0, 4) != "glTF") {
        return {};
    }
    const std::size_t length = little_u32(data, 12);
    if (little_u32(data, 4) == 2 && data.substr(16, 4) == "JSON" && length <= data.size() - 20) {
        return data.substr(20, length);
    }
    return {};
}

// Debian's assimp 5.2.5 computes a strip's or a loop's face count as (vertices - 1) or
// (vertices - 2) in unsigned arithmetic: a line strip, line loop, triangle strip or triangle fan
// with too few vertices (none, when POSITION is missing) asks for 2^32 faces, a 64 GiB
// allocation (fuzz_mesh: a 1 KB .glb). Such primitives are refused before assimp reads the file.
// `json` is the glTF document (a .gltf file, or a .glb's JSON chunk); a document that does not
// parse is left to assimp, which refuses it.
Status check_gltf_primitives(std::string_view json, const std::string& name) {
    // assimp's JSON parser does not validate UTF-8 and nlohmann's does: bytes above 0x7f become
    // 'x' here (every key and number this check reads is ASCII, and JSON's structure is too).
    std::string ascii(json);
    std::replace_if(
        ascii.begin(), ascii.end(), [](char c) { return static_cast<unsigned char>(c) > 0x7f; },
        'x');
    const auto doc = nlohmann::json::parse(ascii, nullptr, false);
    if (doc.is_discarded() || !doc.is_object()) {
        return {};
    }
    const auto count_of = [&](const nlohmann::json& index) -> std::uint64_t {
        const auto accessors = doc.find("accessors");
        if (!index.is_number_unsigned() || accessors == doc.end() || !accessors->is_array() ||
            index.get<std::uint64_t>() >= accessors->size()) {
            return 0;
        }
        const auto& accessor = (*accessors)[index.get<std::size_t>()];
        const auto count = accessor.is_object() ? accessor.find("count") : accessor.end();
        return count != accessor.end() && count->is_number_unsigned() ? count->get<std::uint64_t>()
                                                                      : 0;
    };
    const auto meshes = doc.find("meshes");
    if (meshes == doc.end() || !meshes->is_array()) {
        return {};
    }
    for (std::size_t m = 0; m < meshes->size(); ++m) {
        const auto& mesh = (*meshes)[m];
        const auto primitives = mesh.is_object() ? mesh.find("primitives") : mesh.end();
        if (primitives == mesh.end() || !primitives->is_array()) {
            continue;
        }
        for (std::size_t p = 0; p < primitives->size(); ++p) {
            const auto& primitive = (*primitives)[p];
            if (!primitive.is_object()) {
                continue;
            }
            const auto mode_field = primitive.find("mode");
            const std::uint64_t mode =
                mode_field != primitive.end() && mode_field->is_number_unsigned()
                    ? mode_field->get<std::uint64_t>()
                    : 4;
            // LINE_LOOP 2, LINE_STRIP 3: two vertices at least; TRIANGLE_STRIP 5, TRIANGLE_FAN 6:
            // three.
            const std::uint64_t least = mode == 2 || mode == 3 ? 2 : mode == 5 || mode == 6 ? 3 : 0;
            if (least == 0) {
                continue;
            }
            std::uint64_t vertices = 0;
            if (const auto indices = primitive.find("indices"); indices != primitive.end()) {
                vertices = count_of(*indices);
            } else if (const auto attributes = primitive.find("attributes");
                       attributes != primitive.end() && attributes->is_object() &&
                       attributes->contains("POSITION")) {
                vertices = count_of(attributes->at("POSITION"));
            }
            if (vertices < least) {
                return invalid_argument("mesh file '" + name + "': glTF mesh " + std::to_string(m) +
                                        ", primitive " + std::to_string(p) + ": mode " +
                                        std::to_string(mode) + " needs " + std::to_string(least) +
                                        " vertices at least, it has " + std::to_string(vertices));
            }
        }
    }
    return {};
}

Status unsupported_format(const std::string& name, const std::string& format) {
    return invalid_argument("mesh file '" + name + "': unsupported format '" + format +
                            "' (accepted: " + std::string(ACCEPTED_MESH_FORMATS) + ")");
}

// What read_mesh and read_mesh_from_memory do after reading: validate, then weld.
StatusOr<TriangleMesh> finish(StatusOr<TriangleMesh> read, const std::string& name,
                              const MeshReadOptions& options) {
    if (!read.ok()) {
        return read.status();
    }
    TriangleMesh mesh = std::move(read).value();
    // Validate before welding: the weld's ordered map cannot hold NaN keys.
    if (Status s = validate_mesh(mesh, "mesh file '" + name + "'"); !s.ok()) {
        return s;
    }
    if (options.weld_identical_positions) {
        weld(mesh);
    }
    return mesh;
}

}  // namespace

StatusOr<TriangleMesh> read_mesh(const std::string& path, const MeshReadOptions& options) {
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
    // PLY and OFF are read natively, in double: Debian's assimp reads them at float precision.
    // They are also recognised by content under any other extension (frames without one).
    detail::NativeMeshFormat format = detail::native_format_from_extension(path);
    const bool assimp = format == detail::NativeMeshFormat::none && !extension.empty() &&
                        is_assimp_format(extension.substr(1));
    if (format == detail::NativeMeshFormat::none && !assimp) {
        format = detail::native_format_from_content(read_head(path));
        if (format == detail::NativeMeshFormat::none) {
            return unsupported_format(path, extension.empty() ? "(no extension)" : extension);
        }
    }
    // A .glb or .gltf is read once here to check it (check_glb, check_gltf_primitives) before
    // assimp reads it.
    std::string data;
    if (assimp && extension != ".glb" && extension != ".gltf") {
        return finish(read_with_assimp(path), path, options);
    }
    if (Status s = read_file(path, data); !s.ok()) {
        return s;
    }
    if (assimp) {
        if (extension == ".glb") {
            if (Status s = check_glb(data, path); !s.ok()) {
                return s;
            }
        }
        if (Status s = check_gltf_primitives(gltf_json(data, extension.substr(1)), path); !s.ok()) {
            return s;
        }
        return finish(read_with_assimp(path), path, options);
    }
    return finish(format == detail::NativeMeshFormat::ply ? detail::read_ply(path, data)
                                                          : detail::read_off(path, data),
                  path, options);
}

StatusOr<TriangleMesh> read_mesh_from_memory(std::string_view data, std::string_view format,
                                             const std::string& name,
                                             const MeshReadOptions& options) {
    std::string key = lower(format);
    if (key.starts_with('.')) {
        key.erase(0, 1);
    }
    if (key == "ply") {
        return finish(detail::read_ply(name, data), name, options);
    }
    if (key == "off") {
        return finish(detail::read_off(name, data), name, options);
    }
    if (!is_assimp_format(key)) {
        return unsupported_format(name, std::string(format));
    }
    if (key == "glb") {
        if (Status s = check_glb(data, name); !s.ok()) {
            return s;
        }
    }
    if (Status s = check_gltf_primitives(gltf_json(data, key), name); !s.ok()) {
        return s;
    }
    return finish(read_memory_with_assimp(data, key, name), name, options);
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
