// The public CCD benchmark reader (proxima/io/ccd_queries.hpp): exact rationals rounded to the
// nearest double, the optional truth column, the kind from the path, and a clear error with the
// line number for every malformed file (never a crash).

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include "proxima/io/ccd_queries.hpp"

namespace proxima {
namespace {

namespace fs = std::filesystem;

// Unique per process: ctest runs test cases as parallel processes sharing TempDir().
std::string write_temp(const std::string& name, const std::string& text) {
    const std::string path = ::testing::TempDir() + "proxima_ccd_queries_" +
                             std::to_string(::getpid()) + "_" + name + ".csv";
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out << text;
    return path;
}

// 8 rows: point i at (i, i / 3, -i / 10), truth flag `truth` (empty: 6 columns).
std::string query_rows(const std::string& truth) {
    std::string s;
    for (int i = 0; i < 8; ++i) {
        s += std::to_string(i) + ",1," + std::to_string(i) + ",3," + std::to_string(-i) + ",10";
        s += truth.empty() ? "\n" : "," + truth + "\n";
    }
    return s;
}

std::string error_of(const std::string& name, const std::string& text) {
    const auto path = write_temp(name, text);
    auto r = read_ccd_queries(path);
    fs::remove(path);
    EXPECT_FALSE(r.ok()) << name;
    if (r.ok()) {
        return "";
    }
    EXPECT_EQ(r.status().code(), StatusCode::invalid_argument) << name;
    return r.status().message();
}

TEST(CcdQueries, ReadsSevenAndSixColumns) {
    const auto path = write_temp("good", query_rows("1") + query_rows("0"));
    auto r = read_ccd_queries(path);
    fs::remove(path);
    ASSERT_TRUE(r.ok()) << r.status().to_string();
    ASSERT_EQ(r->size(), 2u);
    EXPECT_EQ(r.value()[0].truth, std::optional<bool>(true));
    EXPECT_EQ(r.value()[1].truth, std::optional<bool>(false));
    for (int i = 0; i < 8; ++i) {
        const auto& p = r.value()[0].points[static_cast<std::size_t>(i)];
        EXPECT_EQ(p.x, static_cast<double>(i));
        EXPECT_EQ(p.y, static_cast<double>(i) / 3.0);  // correctly rounded, as IEEE division
        EXPECT_EQ(p.z, static_cast<double>(-i) / 10.0);
    }
    const auto six = write_temp("six", query_rows("") + "\n\n");  // trailing blank lines
    auto r6 = read_ccd_queries(six);
    fs::remove(six);
    ASSERT_TRUE(r6.ok()) << r6.status().to_string();
    ASSERT_EQ(r6->size(), 1u);
    EXPECT_FALSE(r6.value()[0].truth.has_value());
}

// The in-memory parser (the fuzz target's) is the file reader's: same queries, same messages.
TEST(CcdQueries, ParsesTextLikeTheFileReader) {
    const std::string text = query_rows("1") + query_rows("0");
    const auto path = write_temp("parse", text);
    auto from_file = read_ccd_queries(path);
    fs::remove(path);
    auto from_text = parse_ccd_queries(text, "text.csv");
    ASSERT_TRUE(from_file.ok() && from_text.ok());
    ASSERT_EQ(from_text->size(), from_file->size());
    for (std::size_t q = 0; q < from_text->size(); ++q) {
        EXPECT_EQ(from_text.value()[q].points, from_file.value()[q].points);
        EXPECT_EQ(from_text.value()[q].truth, from_file.value()[q].truth);
    }
    auto bad = parse_ccd_queries("1,0,1,1,1,1\n", "named.csv");
    ASSERT_FALSE(bad.ok());
    EXPECT_EQ(bad.status().message(), "named.csv:1: zero denominator for x");
    // No text at all holds no queries.
    auto empty = parse_ccd_queries("", "empty.csv");
    ASSERT_TRUE(empty.ok());
    EXPECT_TRUE(empty->empty());
}

TEST(CcdQueries, RoundsLongRationalsToNearest) {
    // 34-digit numbers as in the benchmark, CRLF line ends, spaces, an explicit '+'.
    std::string text;
    for (int i = 0; i < 8; ++i) {
        text +=
            "6004799503160661,36028797018963968, 1000000000000000000000000000000001, "
            "3000000000000000000000000000000000,+2,-4,0\r\n";
    }
    const auto path = write_temp("long", text);
    auto r = read_ccd_queries(path);
    fs::remove(path);
    ASSERT_TRUE(r.ok()) << r.status().to_string();
    const auto& p = r.value()[0].points[0];
    EXPECT_EQ(p.x, 6004799503160661.0 / 36028797018963968.0);  // exact dyadic
    EXPECT_EQ(p.y, 1.0 / 3.0);
    EXPECT_EQ(p.z, -0.5);
    // Halfway between 1 and the next double (1 + 2^-53): ties to even gives 1; just above gives
    // the next double.
    text.clear();
    for (int i = 0; i < 8; ++i) {
        text +=
            "9007199254740993,9007199254740992,"     // 1 + 2^-53: tie
            "18014398509481987,18014398509481984,"   // 1 + 3 * 2^-54: above the tie
            "-9007199254740995,9007199254740992\n";  // -(1 + 3 * 2^-53): tie
    }
    const auto ties = write_temp("ties", text);
    auto t = read_ccd_queries(ties);
    fs::remove(ties);
    ASSERT_TRUE(t.ok()) << t.status().to_string();
    const auto& q = t.value()[0].points[3];
    EXPECT_EQ(q.x, 1.0);
    EXPECT_EQ(q.y, 1.0 + 0x1p-52);
    EXPECT_EQ(q.z, -(1.0 + 0x1p-51));  // the even neighbour of -(1 + 1.5 * 2^-52)
}

TEST(CcdQueries, ErrorsNameTheLine) {
    std::string rows = query_rows("0");
    // Line 3 with 5 columns.
    std::string bad = rows;
    auto line3 = bad.find('\n', bad.find('\n') + 1) + 1;
    auto end3 = bad.find('\n', line3);
    bad.replace(line3, end3 - line3, "1,2,3,4,5");
    auto m = error_of("columns", bad);
    EXPECT_NE(m.find(":3:"), std::string::npos) << m;
    EXPECT_NE(m.find("found 5"), std::string::npos) << m;

    // 6 columns after 7.
    bad = rows;
    bad.replace(line3, end3 - line3, "1,2,3,4,5,6");
    m = error_of("mixed", bad);
    EXPECT_NE(m.find(":3:"), std::string::npos) << m;

    // Zero denominator on line 2.
    bad = "1,1,1,1,1,1,0\n1,1,1,0,1,1,0\n" + rows.substr(0, 0);
    m = error_of("zero", bad);
    EXPECT_NE(m.find(":2:"), std::string::npos) << m;
    EXPECT_NE(m.find("zero denominator"), std::string::npos) << m;

    // Not an integer.
    for (const char* token : {"1.5", "abc", "", "1e3", "--1", "0x10"}) {
        m = error_of("nonint", std::string("1,1,") + token + ",1,1,1,0\n");
        EXPECT_NE(m.find(":1:"), std::string::npos) << token << ": " << m;
        EXPECT_NE(m.find("not an integer"), std::string::npos) << token << ": " << m;
    }

    // Not a multiple of 8 rows.
    m = error_of("rows", rows + "1,1,1,1,1,1,0\n");
    EXPECT_NE(m.find("9 rows"), std::string::npos) << m;
    EXPECT_NE(m.find("line 9"), std::string::npos) << m;

    // Not finite as a double (10^400).
    m = error_of("huge", "1" + std::string(400, '0') + ",1,1,1,1,1,0\n");
    EXPECT_NE(m.find("not finite"), std::string::npos) << m;
    EXPECT_NE(m.find(":1:"), std::string::npos) << m;

    // Truth flag other than 0 / 1, and differing within a query.
    m = error_of("flag", "1,1,1,1,1,1,2\n");
    EXPECT_NE(m.find("must be 0 or 1"), std::string::npos) << m;
    bad = rows;
    bad.replace(line3, end3 - line3, "1,1,1,1,1,1,1");
    m = error_of("flags", bad);
    EXPECT_NE(m.find(":3:"), std::string::npos) << m;
    EXPECT_NE(m.find("line 1"), std::string::npos) << m;
}

TEST(CcdQueries, MissingAndEmptyFiles) {
    auto r = read_ccd_queries("/nonexistent/ccd.csv");
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.status().code(), StatusCode::not_found);
    EXPECT_NE(r.status().message().find("/nonexistent/ccd.csv"), std::string::npos);
    const auto empty = write_temp("empty", "");
    auto e = read_ccd_queries(empty);
    fs::remove(empty);
    ASSERT_TRUE(e.ok());
    EXPECT_TRUE(e->empty());
}

TEST(CcdQueries, KindFromPathAndName) {
    EXPECT_EQ(ccd_kind_from_path("a/erleben-spikes/vertex-face/data_0_0.csv"),
              ccd::CcdKind::vertex_face);
    EXPECT_EQ(ccd_kind_from_path("a/edge-edge/data_0_0.csv"), ccd::CcdKind::edge_edge);
    EXPECT_EQ(ccd_kind_from_path("data_0_0.csv"), std::nullopt);
    EXPECT_EQ(ccd_kind_from_path("vertex-face/edge-edge/x.csv"), std::nullopt);
    EXPECT_EQ(parse_ccd_kind("vf"), ccd::CcdKind::vertex_face);
    EXPECT_EQ(parse_ccd_kind("ee"), ccd::CcdKind::edge_edge);
    EXPECT_EQ(parse_ccd_kind("edge-edge"), ccd::CcdKind::edge_edge);
    EXPECT_EQ(parse_ccd_kind("fv"), std::nullopt);
    EXPECT_STREQ(ccd::ccd_kind_name(ccd::CcdKind::vertex_face), "vf");
    EXPECT_STREQ(ccd::ccd_kind_name(ccd::CcdKind::edge_edge), "ee");
}

TEST(CcdQueries, ReadsABenchmarkFile) {
    const fs::path file =
        fs::path(PROXIMA_DATA_DIR) / "ccd-queries" / "unit-tests" / "vertex-face" / "data_0_0.csv";
    if (!fs::exists(file)) {
        GTEST_SKIP() << "CCD benchmark data not found at " << file;
    }
    auto r = read_ccd_queries(file.string());
    ASSERT_TRUE(r.ok()) << r.status().to_string();
    ASSERT_EQ(r->size(), 125u);
    // First row of the file: 0/1, 1/1, 0/1.
    EXPECT_EQ(r.value()[0].points[0].x, 0.0);
    EXPECT_EQ(r.value()[0].points[0].y, 1.0);
    EXPECT_EQ(r.value()[0].points[0].z, 0.0);
    // Fifth row: 0, 2, -1/8388608.
    EXPECT_EQ(r.value()[0].points[4].z, -0x1p-23);
    EXPECT_EQ(r.value()[0].truth, std::optional<bool>(false));
}

}  // namespace
}  // namespace proxima
