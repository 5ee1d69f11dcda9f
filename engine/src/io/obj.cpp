#include "io/obj.hpp"

#include <charconv>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "io/text.hpp"

namespace proxima::detail {

namespace {

bool is_blank(char c) {
    return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f';
}

// One statement of the file: its text (continuation lines joined) and the line it starts on.
class Lines {
  public:
    explicit Lines(std::string_view data) : m_data(data) {}

    bool next(std::string_view& text, std::size_t& line) {
        if (m_at >= m_data.size()) {
            return false;
        }
        line = ++m_line;
        std::string_view piece = take_line();
        if (!continues(piece)) {
            text = piece;
            return true;
        }
        // A backslash at the end of a line joins the next one (a space in its place).
        m_joined.clear();
        while (continues(piece) && m_at < m_data.size()) {
            piece = trim_right(piece);
            m_joined.append(piece.substr(0, piece.size() - 1));
            m_joined.push_back(' ');
            ++m_line;
            piece = take_line();
        }
        m_joined.append(continues(piece) ? trim_right(piece).substr(0, trim_right(piece).size() - 1)
                                         : piece);
        text = m_joined;
        return true;
    }

  private:
    static std::string_view trim_right(std::string_view s) {
        while (!s.empty() && is_blank(s.back())) {
            s.remove_suffix(1);
        }
        return s;
    }
    static bool continues(std::string_view s) {
        s = trim_right(s);
        return !s.empty() && s.back() == '\\';
    }
    // Up to the next "\n", "\r\n" or "\r".
    std::string_view take_line() {
        const std::size_t start = m_at;
        while (m_at < m_data.size() && m_data[m_at] != '\n' && m_data[m_at] != '\r') {
            ++m_at;
        }
        const std::string_view line = m_data.substr(start, m_at - start);
        if (m_at < m_data.size() && m_data[m_at] == '\r') {
            ++m_at;
        }
        if (m_at < m_data.size() && m_data[m_at] == '\n') {
            ++m_at;
        }
        return line;
    }

    std::string_view m_data;
    std::size_t m_at = 0;
    std::size_t m_line = 0;
    std::string m_joined;
};

// Whitespace-separated tokens of a statement, up to a '#' comment.
std::string_view next_token(std::string_view& rest) {
    std::size_t i = 0;
    while (i < rest.size() && is_blank(rest[i])) {
        ++i;
    }
    if (i == rest.size() || rest[i] == '#') {
        rest = {};
        return {};
    }
    std::size_t j = i;
    while (j < rest.size() && !is_blank(rest[j]) && rest[j] != '#') {
        ++j;
    }
    const std::string_view token = rest.substr(i, j - i);
    rest.remove_prefix(j);
    return token;
}

// The vertex part of a face corner ("7", "7/2", "7//3", "7/2/3"); false when it is not an integer.
bool parse_corner(std::string_view token, std::int64_t& out) {
    const std::size_t slash = token.find('/');
    std::string_view number = token.substr(0, slash);
    if (!number.empty() && number.front() == '+') {
        number.remove_prefix(1);
        if (!number.empty() && number.front() == '-') {
            return false;  // "+-3"
        }
    }
    if (number.empty()) {
        return false;
    }
    const auto [end, ec] = std::from_chars(number.data(), number.data() + number.size(), out);
    return ec == std::errc() && end == number.data() + number.size();
}

struct Point2 {
    double x;
    double y;
};

double cross(const Point2& o, const Point2& a, const Point2& b) {
    return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x);
}

// Ear clipping budget: point-in-triangle tests over the whole file. Convex polygons need none;
// a non-convex polygon needs about (corners x reflex corners) per ear.
constexpr std::uint64_t EAR_TEST_BUDGET = 200'000'000;

class Triangulator {
  public:
    // Appends the triangles of polygon `corners` (indices into `positions`) to `out`. False when
    // the work budget is spent.
    bool run(const std::vector<Vec3>& positions, const std::vector<std::uint32_t>& corners,
             std::vector<TriangleIndices>& out) {
        const std::size_t n = corners.size();
        if (n == 3) {
            out.push_back({corners[0], corners[1], corners[2]});
            return true;
        }
        project(positions, corners);
        m_left.resize(n);
        for (std::size_t i = 0; i < n; ++i) {
            m_left[i] = i;
        }
        // Clip from the second corner on: a convex polygon becomes the fan from its first corner.
        std::size_t at = 1;
        std::size_t misses = 0;
        while (m_left.size() > 3) {
            const std::size_t m = m_left.size();
            at %= m;
            const std::size_t prev = m_left[(at + m - 1) % m];
            const std::size_t cur = m_left[at];
            const std::size_t next = m_left[(at + 1) % m];
            bool ear = m_sign * cross(m_flat[prev], m_flat[cur], m_flat[next]) >= 0;
            for (std::size_t k = 0; ear && k < m; ++k) {
                const std::size_t other = m_left[k];
                if (other == prev || other == cur || other == next || !is_reflex(k)) {
                    continue;
                }
                if (++m_tests > EAR_TEST_BUDGET) {
                    return false;
                }
                ear = !inside(m_flat[other], m_flat[prev], m_flat[cur], m_flat[next]);
            }
            if (ear) {
                out.push_back({corners[prev], corners[cur], corners[next]});
                m_left.erase(m_left.begin() + static_cast<std::ptrdiff_t>(at));
                misses = 0;
                continue;
            }
            ++at;
            if (++misses == m) {
                // No ear: not a simple polygon (or degenerate in its plane). The rest becomes a
                // fan, as assimp's triangulation did.
                break;
            }
        }
        for (std::size_t k = 1; k + 1 < m_left.size(); ++k) {
            out.push_back({corners[m_left[0]], corners[m_left[k]], corners[m_left[k + 1]]});
        }
        return true;
    }

  private:
    // Into the plane of the polygon's Newell normal, dropping its largest component.
    void project(const std::vector<Vec3>& positions, const std::vector<std::uint32_t>& corners) {
        const std::size_t n = corners.size();
        double nx = 0;
        double ny = 0;
        double nz = 0;
        for (std::size_t i = 0; i < n; ++i) {
            const Vec3& a = positions[corners[i]];
            const Vec3& b = positions[corners[(i + 1) % n]];
            nx += (a.y - b.y) * (a.z + b.z);
            ny += (a.z - b.z) * (a.x + b.x);
            nz += (a.x - b.x) * (a.y + b.y);
        }
        const double ax = std::abs(nx);
        const double ay = std::abs(ny);
        const double az = std::abs(nz);
        m_flat.resize(n);
        for (std::size_t i = 0; i < n; ++i) {
            const Vec3& p = positions[corners[i]];
            if (az >= ax && az >= ay) {
                m_flat[i] = {p.x, p.y};
            } else if (ax >= ay) {
                m_flat[i] = {p.y, p.z};
            } else {
                m_flat[i] = {p.z, p.x};
            }
        }
        const double dominant = az >= ax && az >= ay ? nz : ax >= ay ? nx : ny;
        m_sign = dominant < 0 ? -1.0 : 1.0;
    }
    bool is_reflex(std::size_t k) const {
        const std::size_t m = m_left.size();
        return m_sign * cross(m_flat[m_left[(k + m - 1) % m]], m_flat[m_left[k]],
                              m_flat[m_left[(k + 1) % m]]) <
               0;
    }
    // p inside or on triangle (a, b, c) of orientation m_sign, and not at one of its corners.
    bool inside(const Point2& p, const Point2& a, const Point2& b, const Point2& c) const {
        const auto same = [](const Point2& u, const Point2& v) { return u.x == v.x && u.y == v.y; };
        if (same(p, a) || same(p, b) || same(p, c)) {
            return false;
        }
        return m_sign * cross(a, b, p) >= 0 && m_sign * cross(b, c, p) >= 0 &&
               m_sign * cross(c, a, p) >= 0;
    }

    std::vector<Point2> m_flat;
    std::vector<std::size_t> m_left;
    double m_sign = 1.0;
    std::uint64_t m_tests = 0;
};

}  // namespace

StatusOr<TriangleMesh> read_obj(const std::string& name, std::string_view data) {
    const auto error = [&](std::size_t line, const std::string& what) {
        return invalid_argument("mesh file '" + name + "': line " + std::to_string(line) + ": " +
                                what);
    };
    std::vector<Vec3> positions;
    // Faces keep the file's vertex numbers (1-based; negative ones resolved when read) until the
    // whole file is read, since faces may name vertices defined after them.
    std::vector<std::int64_t> corners;
    struct Face {
        std::size_t first;
        std::size_t count;
        std::size_t line;
    };
    std::vector<Face> faces;

    Lines lines(data);
    std::string_view text;
    std::size_t line = 0;
    while (lines.next(text, line)) {
        std::string_view rest = text;
        const std::string_view keyword = next_token(rest);
        if (keyword == "v") {
            double xyz[3];
            for (double& c : xyz) {
                const std::string_view token = next_token(rest);
                if (token.empty()) {
                    return error(line, "a vertex needs three coordinates");
                }
                if (!parse_double(token, c)) {
                    return error(line, "'" + printable(token) + "' is not a number");
                }
            }
            positions.push_back({xyz[0], xyz[1], xyz[2]});
        } else if (keyword == "f") {
            const std::size_t first = corners.size();
            for (std::string_view token = next_token(rest); !token.empty();
                 token = next_token(rest)) {
                std::int64_t index = 0;
                if (!parse_corner(token, index) || index == 0) {
                    return error(line, "'" + printable(token) + "' is not a face corner");
                }
                if (index < 0) {
                    // Counts back from the last vertex read so far.
                    if (static_cast<std::uint64_t>(-(index + 1)) >= positions.size()) {
                        return error(line, "vertex " + std::to_string(index) + " of " +
                                               std::to_string(positions.size()) + " read so far");
                    }
                    index = static_cast<std::int64_t>(positions.size()) + index + 1;
                }
                corners.push_back(index);
            }
            if (corners.size() - first >= 3) {
                faces.push_back({first, corners.size() - first, line});
            } else {
                corners.resize(first);  // a point or a line
            }
        }
        // Everything else (vt, vn, vp, l, p, o, g, s, usemtl, mtllib, curves, ...) carries no
        // triangle; no other file is opened.
    }

    TriangleMesh mesh;
    std::vector<std::uint32_t> renumber(positions.size(),
                                        std::numeric_limits<std::uint32_t>::max());
    std::vector<std::uint32_t> polygon;
    Triangulator triangulator;
    for (const Face& face : faces) {
        polygon.clear();
        for (std::size_t k = 0; k < face.count; ++k) {
            const std::int64_t index = corners[face.first + k];
            if (static_cast<std::uint64_t>(index) > positions.size()) {
                return error(face.line, "vertex " + std::to_string(index) + " of " +
                                            std::to_string(positions.size()));
            }
            std::uint32_t& kept = renumber[static_cast<std::size_t>(index - 1)];
            if (kept == std::numeric_limits<std::uint32_t>::max()) {
                if (mesh.vertices.size() >= std::numeric_limits<std::uint32_t>::max()) {
                    return error(face.line, "too many vertices");
                }
                kept = static_cast<std::uint32_t>(mesh.vertices.size());
                mesh.vertices.push_back(positions[static_cast<std::size_t>(index - 1)]);
            }
            polygon.push_back(kept);
        }
        if (!triangulator.run(mesh.vertices, polygon, mesh.triangles)) {
            return error(face.line,
                         "the non-convex polygons of this file need more work to triangulate "
                         "than is allowed (" +
                             std::to_string(EAR_TEST_BUDGET) + " tests)");
        }
    }
    return mesh;
}

}  // namespace proxima::detail
