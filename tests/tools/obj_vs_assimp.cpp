// Cross-check of the engine's OBJ reader against the importer it replaced (Debian's assimp 5.2.5,
// used here as the peer only, never by the product): for every .obj under a folder, both read the
// file (assimp with aiProcess_Triangulate, as read_mesh did until 2026-11-24; no welding on either
// side) and the tool prints, per file that differs, the triangle counts, the total areas and the
// number of distinct vertices used (rounded to float, as assimp stores them), then a summary.
//
//   build/release/tests/proxima_obj_vs_assimp ../shared/data/meshes
//
// Differences are expected where a polygon is not planar (its triangulation is a choice: the
// engine fans convex polygons from their first corner and ear-clips the others in the plane of
// their Newell normal, assimp ear-clips from another corner) and where assimp's ear clipping finds
// no ear (it then drops the rest of the polygon; the engine fans it). docs/reliability.md quotes
// this tool's summary.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <set>
#include <string>

#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <assimp/Importer.hpp>

#include "proxima/io/mesh_io.hpp"

namespace {

double area(const proxima::Vec3& a, const proxima::Vec3& b, const proxima::Vec3& c) {
    const double ux = b.x - a.x, uy = b.y - a.y, uz = b.z - a.z;
    const double vx = c.x - a.x, vy = c.y - a.y, vz = c.z - a.z;
    const double x = uy * vz - uz * vy, y = uz * vx - ux * vz, z = ux * vy - uy * vx;
    return 0.5 * std::sqrt(x * x + y * y + z * z);
}

}  // namespace

int main(int argc, char** argv) {
    if (argc != 2) {
        std::fprintf(stderr, "usage: %s FOLDER\n", argv[0]);
        return 2;
    }
    int files = 0;
    int same = 0;
    int own_failed = 0;
    int assimp_failed = 0;
    int count_differs = 0;
    for (const auto& entry : std::filesystem::recursive_directory_iterator(argv[1])) {
        if (entry.path().extension() != ".obj") {
            continue;
        }
        ++files;
        const std::string path = entry.path().string();
        proxima::MeshReadOptions no_weld;
        no_weld.weld = proxima::WeldMode::never;
        const auto own = proxima::read_mesh(path, no_weld);
        Assimp::Importer importer;
        const aiScene* scene = importer.ReadFile(path, aiProcess_Triangulate);
        if (!own.ok()) {
            ++own_failed;
            std::printf("%s: engine: %s\n", path.c_str(), own.status().to_string().c_str());
            continue;
        }
        if (scene == nullptr) {
            ++assimp_failed;
            std::printf("%s: assimp: %s\n", path.c_str(), importer.GetErrorString());
            continue;
        }
        std::size_t assimp_triangles = 0;
        double assimp_area = 0;
        std::set<std::array<float, 3>> assimp_vertices;
        for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
            const aiMesh* mesh = scene->mMeshes[m];
            for (unsigned f = 0; f < mesh->mNumFaces; ++f) {
                const aiFace& face = mesh->mFaces[f];
                if (face.mNumIndices != 3) {
                    continue;
                }
                ++assimp_triangles;
                proxima::Vec3 p[3];
                for (int k = 0; k < 3; ++k) {
                    const aiVector3D v = mesh->mVertices[face.mIndices[k]];
                    p[k] = {v.x, v.y, v.z};
                    assimp_vertices.insert({v.x, v.y, v.z});
                }
                assimp_area += area(p[0], p[1], p[2]);
            }
        }
        double own_area = 0;
        std::set<std::array<float, 3>> own_vertices;
        for (const auto& t : own->triangles) {
            own_area += area(own->vertices[t[0]], own->vertices[t[1]], own->vertices[t[2]]);
            for (const auto i : t) {
                const auto& v = own->vertices[i];
                own_vertices.insert(
                    {static_cast<float>(v.x), static_cast<float>(v.y), static_cast<float>(v.z)});
            }
        }
        const bool counts = assimp_triangles == own->triangles.size();
        const bool areas =
            std::abs(assimp_area - own_area) <= 1e-6 * std::max(1.0, std::abs(assimp_area));
        const bool vertices = assimp_vertices.size() == own_vertices.size();
        if (counts && areas && vertices) {
            ++same;
            continue;
        }
        count_differs += counts ? 0 : 1;
        std::printf("%s: triangles %zu (assimp) %zu (engine), area %.9g %.9g, vertices %zu %zu\n",
                    path.c_str(), assimp_triangles, own->triangles.size(), assimp_area, own_area,
                    assimp_vertices.size(), own_vertices.size());
    }
    std::printf(
        "%d OBJ files: %d agree (triangle count, total area within 1e-6, distinct vertices), "
        "%d differ (%d in triangle count); the engine refused %d, assimp %d\n",
        files, same, files - same - own_failed - assimp_failed, count_differs, own_failed,
        assimp_failed);
    return own_failed == 0 ? 0 : 1;
}
