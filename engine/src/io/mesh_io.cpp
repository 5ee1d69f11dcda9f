#include "proxima/io/mesh_io.hpp"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <system_error>
#include <tuple>

#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <assimp/Importer.hpp>

#include "io/ply_off.hpp"

namespace proxima {

namespace {

void collect(const aiScene* scene, const aiNode* node, const aiMatrix4x4& parent, TriangleMesh& out,
             std::size_t& skipped) {
    const aiMatrix4x4 transform = parent * node->mTransformation;
    const bool identity = transform.IsIdentity();
    for (unsigned m = 0; m < node->mNumMeshes; ++m) {
        const aiMesh* mesh = scene->mMeshes[node->mMeshes[m]];
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
                ++skipped;  // points and lines (polygons were triangulated on import)
                continue;
            }
            out.triangles.push_back(
                {base + face.mIndices[0], base + face.mIndices[1], base + face.mIndices[2]});
        }
    }
    for (unsigned c = 0; c < node->mNumChildren; ++c) {
        collect(scene, node->mChildren[c], transform, out, skipped);
    }
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

StatusOr<TriangleMesh> read_with_assimp(const std::string& path) {
    Assimp::Importer importer;
    // Keep what assimp reads as it is: no joining (it would also merge on normals and UVs), no
    // reordering. Triangulation keeps polygon order; degenerate triangles are kept (they are
    // legal input for every query).
    const aiScene* scene = importer.ReadFile(path, aiProcess_Triangulate);
    if (scene == nullptr || scene->mRootNode == nullptr) {
        return invalid_argument("mesh file '" + path +
                                "': cannot be read: " + importer.GetErrorString());
    }
    TriangleMesh mesh;
    std::size_t skipped = 0;
    collect(scene, scene->mRootNode, aiMatrix4x4(), mesh, skipped);
    return mesh;
}

StatusOr<TriangleMesh> read_native(const std::string& path, detail::NativeMeshFormat format) {
    std::string data;
    if (Status s = read_file(path, data); !s.ok()) {
        return s;
    }
    return format == detail::NativeMeshFormat::ply ? detail::read_ply(path, data)
                                                   : detail::read_off(path, data);
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
    // PLY and OFF are read natively, in double: Debian's assimp reads them at float precision.
    detail::NativeMeshFormat format = detail::native_format_from_extension(path);
    if (format == detail::NativeMeshFormat::none) {
        format = detail::native_format_from_content(read_head(path));
    }
    StatusOr<TriangleMesh> read = format == detail::NativeMeshFormat::none
                                      ? read_with_assimp(path)
                                      : read_native(path, format);
    if (!read.ok()) {
        return read.status();
    }
    TriangleMesh mesh = std::move(read).value();
    // Validate before welding: the weld's ordered map cannot hold NaN keys.
    if (Status s = validate_mesh(mesh, "mesh file '" + path + "'"); !s.ok()) {
        return s;
    }
    if (options.weld_identical_positions) {
        weld(mesh);
    }
    return mesh;
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
