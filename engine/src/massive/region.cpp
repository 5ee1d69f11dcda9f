#include "proxima/massive/region.hpp"

#include <algorithm>
#include <cmath>
#include <tuple>
#include <utility>

namespace proxima::massive {

double box_distance(const Aabb& box, const Vec3& p) {
    const auto axis = [](double lo, double hi, double x) {
        if (x < lo) {
            return lo - x;
        }
        if (x > hi) {
            return x - hi;
        }
        return 0.0;
    };
    const double dx = axis(box.lo.x, box.hi.x, p.x);
    const double dy = axis(box.lo.y, box.hi.y, p.y);
    const double dz = axis(box.lo.z, box.hi.z, p.z);
    return std::sqrt(dx * dx + dy * dy + dz * dz);
}

Status check_region_request(const RegionRequest& request, std::uint32_t object_count) {
    const Vec3& c = request.center;
    if (!std::isfinite(c.x) || !std::isfinite(c.y) || !std::isfinite(c.z)) {
        return invalid_argument("center must be finite (no NaN or Inf coordinate)");
    }
    if (!std::isfinite(request.radius) || request.radius < 0.0) {
        return invalid_argument("radius must be a finite distance >= 0 (0: the whole model), got " +
                                std::to_string(request.radius));
    }
    for (std::size_t i = 0; i < request.objects.size(); ++i) {
        if (request.objects[i] >= object_count) {
            return invalid_argument(
                "objects[" + std::to_string(i) + "]: object " + std::to_string(request.objects[i]) +
                " is out of range (the model has " + std::to_string(object_count) + " objects)");
        }
    }
    return {};
}

RegionPlan plan_region(const Store& store, const ModelView::Snapshot* snapshot,
                       const RegionRequest& request) {
    std::vector<std::uint8_t> wanted;  // empty: every object
    if (!request.objects.empty()) {
        std::uint32_t n = 0;
        for (auto o : request.objects) {
            n = std::max(n, o + 1);
        }
        wanted.assign(n, 0);
        for (auto o : request.objects) {
            wanted[o] = 1;
        }
    }
    const auto selected_object = [&](std::uint32_t object) {
        return wanted.empty() || (object < wanted.size() && wanted[object] != 0);
    };
    const bool everything = request.radius == 0.0;
    RegionPlan plan;
    const auto consider = [&](RegionPieceRef ref) {
        if (!selected_object(ref.object)) {
            return;
        }
        if (!everything) {
            ref.distance = box_distance(ref.box, request.center);
            if (!(ref.distance <= request.radius)) {
                return;
            }
        }
        plan.pieces.push_back(ref);
    };
    const auto& pieces = store.pieces();
    for (std::uint32_t p = 0; p < pieces.size(); ++p) {
        const auto& info = pieces[p];
        if (snapshot != nullptr && info.object < snapshot->masked.size() &&
            snapshot->masked[info.object] != 0) {
            continue;  // deleted, or moved (its overlay piece stands in for it)
        }
        RegionPieceRef ref;
        ref.object = info.object;
        ref.piece = p;
        ref.box = info.box;
        ref.triangles = info.triangle_count;
        consider(ref);
    }
    if (snapshot != nullptr) {
        for (std::size_t i = 0; i < snapshot->overlay.size(); ++i) {
            const auto& o = snapshot->overlay[i];
            RegionPieceRef ref;
            ref.object = o.object;
            ref.overlay = true;
            ref.overlay_index = i;
            ref.box = o.box;
            ref.triangles = static_cast<std::uint32_t>(o.piece->geometry.triangles.size());
            consider(ref);
        }
    }
    std::sort(plan.pieces.begin(), plan.pieces.end(), [](const auto& a, const auto& b) {
        return std::tie(a.distance, a.object, a.piece) < std::tie(b.distance, b.object, b.piece);
    });
    if (request.max_triangles != 0) {
        std::size_t keep = 0;
        std::uint64_t sum = 0;
        while (keep < plan.pieces.size() &&
               sum + plan.pieces[keep].triangles <= request.max_triangles) {
            sum += plan.pieces[keep].triangles;
            ++keep;
        }
        plan.truncated = keep < plan.pieces.size();
        plan.pieces.resize(keep);
    }
    for (const auto& ref : plan.pieces) {
        plan.triangles += ref.triangles;
    }
    return plan;
}

StatusOr<RegionPiece> read_region_piece(const std::shared_ptr<const Store>& store,
                                        GeometryCache& cache, const ModelView::Snapshot* snapshot,
                                        const RegionPieceRef& ref) {
    RegionPiece out;
    out.object = ref.object;
    out.box = ref.box;
    out.distance = ref.distance;
    const auto copy = [&](const PieceGeometry& g) {
        out.vertices = g.vertices;
        out.triangles = g.triangles;
        out.triangle_ids = g.source_ids();
    };
    if (ref.overlay) {
        const auto& o = snapshot->overlay.at(ref.overlay_index);
        out.object_name = o.name;
        copy(o.piece->geometry);
        return out;
    }
    out.object_name = store->objects().at(ref.object).name;
    auto handle = cache.get(store, ref.piece);
    if (!handle.ok()) {
        return handle.status();
    }
    copy(handle.value()->geometry);
    return out;
}

}  // namespace proxima::massive
