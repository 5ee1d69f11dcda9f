// Reader of the public CCD benchmark format (proxima/io/ccd_queries.hpp). Coordinates are exact
// rationals with numbers of any length; GMP holds them exactly and the conversion to double is
// correctly rounded (mpq_get_d truncates, so the neighbour away from zero is compared exactly).

#include "proxima/io/ccd_queries.hpp"

#include <gmp.h>

#include <bit>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

namespace proxima {

namespace {

// RAII holders for the GMP values used while reading.
struct Rational {
    mpq_t q;
    Rational() { mpq_init(q); }
    ~Rational() { mpq_clear(q); }
    Rational(const Rational&) = delete;
    Rational& operator=(const Rational&) = delete;
};

struct Integer {
    mpz_t z;
    Integer() { mpz_init(z); }
    ~Integer() { mpz_clear(z); }
    Integer(const Integer&) = delete;
    Integer& operator=(const Integer&) = delete;
};

std::string_view trim(std::string_view s) {
    while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) {
        s.remove_prefix(1);
    }
    while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r')) {
        s.remove_suffix(1);
    }
    return s;
}

// An optionally signed decimal integer: digits only, at least one.
bool is_integer(std::string_view s) {
    if (!s.empty() && (s.front() == '+' || s.front() == '-')) {
        s.remove_prefix(1);
    }
    if (s.empty()) {
        return false;
    }
    for (char c : s) {
        if (c < '0' || c > '9') {
            return false;
        }
    }
    return true;
}

// Sets z from a token that passed is_integer.
void set_integer(mpz_t z, std::string_view s) {
    if (!s.empty() && s.front() == '+') {
        s.remove_prefix(1);
    }
    const std::string str(s);
    mpz_set_str(z, str.c_str(), 10);
}

// The double nearest to q (ties to even); false when |q| exceeds the largest double.
bool nearest_double(const mpq_t q, double& out, mpq_t scratch) {
    mpq_abs(scratch, q);
    {
        Rational largest;
        mpq_set_d(largest.q, std::numeric_limits<double>::max());
        if (mpq_cmp(scratch, largest.q) > 0) {
            return false;
        }
    }
    const int sign = mpq_sgn(q);
    double d = mpq_get_d(q);  // truncated toward zero: |d| <= |q|
    if (sign == 0 || !std::isfinite(d)) {
        out = sign == 0 ? 0.0 : d;
        return sign == 0;
    }
    const double away = std::nextafter(d, sign > 0 ? std::numeric_limits<double>::infinity()
                                                   : -std::numeric_limits<double>::infinity());
    if (!std::isfinite(away)) {
        out = d;  // |q| <= DBL_MAX: d is the largest double, the nearest
        return true;
    }
    // Compare |q - d| with |away - q|, both exactly.
    Rational below;
    Rational above;
    mpq_set_d(scratch, d);
    mpq_sub(below.q, q, scratch);
    mpq_abs(below.q, below.q);
    mpq_set_d(scratch, away);
    mpq_sub(above.q, scratch, q);
    mpq_abs(above.q, above.q);
    const int c = mpq_cmp(above.q, below.q);
    if (c < 0 || (c == 0 && (std::bit_cast<std::uint64_t>(d) & 1u) != 0)) {
        d = away;
    }
    out = d;
    return true;
}

Status error_at(const std::string& path, std::size_t line, const std::string& what) {
    return invalid_argument(path + ":" + std::to_string(line) + ": " + what);
}

}  // namespace

StatusOr<std::vector<CcdQuery>> read_ccd_queries(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) {
        return not_found("cannot open CCD query file '" + path + "'");
    }
    std::stringstream buffer;
    buffer << in.rdbuf();
    if (in.bad()) {
        return invalid_argument("cannot read CCD query file '" + path + "'");
    }
    return parse_ccd_queries(buffer.str(), path);
}

StatusOr<std::vector<CcdQuery>> parse_ccd_queries(std::string_view text, const std::string& path) {
    std::vector<CcdQuery> queries;
    Rational value;
    Rational scratch;
    Integer num;
    Integer den;

    std::size_t line_number = 0;
    std::size_t rows = 0;
    std::size_t columns = 0;  // of the first row
    std::size_t query_first_line = 0;
    std::vector<std::string_view> fields;
    std::size_t pos = 0;
    while (pos < text.size()) {
        std::size_t end = text.find('\n', pos);
        if (end == std::string_view::npos) {
            end = text.size();
        }
        const std::string_view line = trim(text.substr(pos, end - pos));
        pos = end + 1;
        ++line_number;
        if (line.empty()) {
            continue;
        }
        fields.clear();
        std::size_t start = 0;
        while (true) {
            const std::size_t comma = line.find(',', start);
            fields.push_back(trim(line.substr(
                start, comma == std::string_view::npos ? std::string_view::npos : comma - start)));
            if (comma == std::string_view::npos) {
                break;
            }
            start = comma + 1;
        }
        if (fields.size() != 6 && fields.size() != 7) {
            return error_at(path, line_number,
                            "expected 6 or 7 comma-separated columns (x_num, x_den, y_num, y_den, "
                            "z_num, z_den[, truth]), found " +
                                std::to_string(fields.size()));
        }
        if (columns == 0) {
            columns = fields.size();
        } else if (fields.size() != columns) {
            return error_at(path, line_number,
                            std::to_string(fields.size()) + " columns, but the first row has " +
                                std::to_string(columns));
        }
        for (std::size_t i = 0; i < fields.size(); ++i) {
            if (!is_integer(fields[i])) {
                return error_at(path, line_number,
                                "column " + std::to_string(i + 1) + " is not an integer: '" +
                                    std::string(fields[i].substr(0, 40)) + "'");
            }
        }
        const std::size_t row = rows % 8;
        if (row == 0) {
            queries.emplace_back();
            query_first_line = line_number;
        }
        CcdQuery& query = queries.back();
        static constexpr const char* AXIS = "xyz";
        for (int k = 0; k < 3; ++k) {
            const std::size_t at = 2 * static_cast<std::size_t>(k);
            set_integer(num.z, fields[at]);
            set_integer(den.z, fields[at + 1]);
            if (mpz_sgn(den.z) == 0) {
                return error_at(path, line_number, std::string("zero denominator for ") + AXIS[k]);
            }
            mpq_set_num(value.q, num.z);
            mpq_set_den(value.q, den.z);
            mpq_canonicalize(value.q);
            double d = 0.0;
            if (!nearest_double(value.q, d, scratch.q)) {
                return error_at(path, line_number,
                                std::string(1, AXIS[k]) +
                                    " is not finite as a double (magnitude above 1.8e308)");
            }
            query.points[row][k] = d;
        }
        if (columns == 7) {
            const std::string_view flag = fields[6];
            if (flag != "0" && flag != "1") {
                return error_at(path, line_number,
                                "truth flag (column 7) must be 0 or 1, found '" +
                                    std::string(flag.substr(0, 40)) + "'");
            }
            const bool truth = flag == "1";
            if (row == 0) {
                query.truth = truth;
            } else if (*query.truth != truth) {
                return error_at(path, line_number,
                                "truth flag differs from the query's first row (line " +
                                    std::to_string(query_first_line) + ")");
            }
        }
        ++rows;
    }
    if (rows % 8 != 0) {
        return invalid_argument(path + ": " + std::to_string(rows) +
                                " rows, not a multiple of 8 (8 points per query); the last query "
                                "starts at line " +
                                std::to_string(query_first_line));
    }
    return queries;
}

std::optional<ccd::CcdKind> ccd_kind_from_path(std::string_view path) {
    const bool vf = path.find("vertex-face") != std::string_view::npos;
    const bool ee = path.find("edge-edge") != std::string_view::npos;
    if (vf == ee) {
        return std::nullopt;
    }
    return vf ? ccd::CcdKind::vertex_face : ccd::CcdKind::edge_edge;
}

std::optional<ccd::CcdKind> parse_ccd_kind(std::string_view name) {
    if (name == "vf" || name == "vertex-face" || name == "vertex_face") {
        return ccd::CcdKind::vertex_face;
    }
    if (name == "ee" || name == "edge-edge" || name == "edge_edge") {
        return ccd::CcdKind::edge_edge;
    }
    return std::nullopt;
}

}  // namespace proxima
